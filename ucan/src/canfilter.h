/* canfilter.h - CAN_RAW receive filtering exactly as linux net/can/af_can.c
 * and raw.c decide it, shared by the hub and the unit tests. */
#ifndef UCAN_CANFILTER_H
#define UCAN_CANFILTER_H

#include <stdint.h>
#include <linux/can.h>

/* Does a CAN_RAW socket with these filters accept a frame with can_id?
 * Error frames (CAN_ERR_FLAG) are matched only against err_mask; other frames
 * against the filter list (OR, or AND with CAN_RAW_JOIN_FILTERS). */
int can_raw_accepts(canid_t can_id, const struct can_filter *filters, uint32_t nfilters,
		    uint32_t err_mask, int join_filters);

/* Test only: a deliberately broken emulation (filters ignore the RTR bit), set by
 * ucan-hub from UCAN_HUB_TEST_FAULT=ignore-rtr-filter, so the differential check
 * against kernel vcan can prove it catches a filter bug. */
extern int can_filter_test_ignore_rtr;

#endif
