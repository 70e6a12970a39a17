/* canframelen.h - wire length and arbitration priority of CAN frames, for the
 * hub's optional bitrate emulation and bus-load statistics. */
#ifndef UCAN_CANFRAMELEN_H
#define UCAN_CANFRAMELEN_H

#include <stdint.h>
#include <linux/can.h>
#include "ucan_proto.h"

/* Bits on the wire including the 3-bit inter-frame space (can-utils
 * canframelen.c conventions): SFF 47 + 8n unstuffed, 55 + 10n worst case;
 * EFF 67 + 8n / 80 + 10n. CAN FD frames are timed as classic frames of the
 * same payload at the nominal rate (no data-phase bitrate is modelled). */
unsigned can_frame_bits(const struct canfd_frame *frame, int is_fd, enum ucan_stuffing stuffing);

/* Arbitration key: the frame with the lower key wins the bus. Encodes the
 * bits in the order they are sent (11-bit base id, RTR/SRR, IDE, 18-bit
 * extension, RTR), so a standard frame beats an extended one with the same
 * base id and a data frame beats a remote frame with the same id. */
uint32_t can_arbitration_key(canid_t can_id);

#endif
