/* canfilter.c - see canfilter.h. Mirrors can_rcv_list_find() (filter
 * normalisation at registration) and can_rcv_filter() + raw_rcv() (matching,
 * duplicate elimination, join) of linux 6.1. */
#include "canfilter.h"

#define CAN_EFF_RTR_FLAGS (CAN_EFF_FLAG | CAN_RTR_FLAG)

int can_filter_test_ignore_rtr;

static int filter_matches(canid_t can_id, struct can_filter filter)
{
	canid_t inverted = filter.can_id & CAN_INV_FILTER;
	canid_t mask = filter.can_mask;
	canid_t want = filter.can_id;

	if (mask & CAN_ERR_FLAG)
		return 0; /* kernel files these under the error list: never match data frames */
	/* 'SFF only' filters: an EFF-flag mask with a SFF id ignores the upper id bits */
	if ((mask & CAN_EFF_FLAG) && !(want & CAN_EFF_FLAG))
		mask &= (CAN_SFF_MASK | CAN_EFF_RTR_FLAGS);
	if (can_filter_test_ignore_rtr)
		mask &= ~CAN_RTR_FLAG;
	want &= mask;
	if (inverted)
		return (can_id & mask) != want;
	return (can_id & mask) == want;
}

int can_raw_accepts(canid_t can_id, const struct can_filter *filters, uint32_t nfilters,
		    uint32_t err_mask, int join_filters)
{
	uint32_t matches = 0;

	if (can_id & CAN_ERR_FLAG) {
		/* the error list holds err_mask and any filter whose mask has CAN_ERR_FLAG */
		matches = (can_id & err_mask & CAN_ERR_MASK) ? 1 : 0;
		for (uint32_t i = 0; i < nfilters; i++)
			if ((filters[i].can_mask & CAN_ERR_FLAG) &&
			    (can_id & filters[i].can_mask & CAN_ERR_MASK))
				matches++;
	} else {
		for (uint32_t i = 0; i < nfilters; i++)
			matches += (uint32_t)filter_matches(can_id, filters[i]);
	}
	if (matches == 0)
		return 0;
	/* raw_rcv(): with join, deliver only once every filter has matched */
	return !join_filters || matches >= nfilters;
}
