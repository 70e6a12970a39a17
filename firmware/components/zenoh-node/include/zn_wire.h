/* zenoh_serialize.h - the bridge's 16-byte wire format for one CAN 2.0 frame.
 *
 * Little-endian, byte by byte (no struct punning):
 *   bytes 0-3   id        u32  11-bit (extd = 0) or 29-bit (extd = 1) identifier
 *   byte  4     dlc       u8   0..8
 *   byte  5     flags     u8   bit0 extended id, bit1 remote frame, bits 2-7 = 0
 *   bytes 6-7   reserved  u16  = 0
 *   bytes 8-15  data[8]        bytes beyond dlc (all bytes of a remote frame) = 0
 * Worked example: standard id 0x123, dlc 2, data DE AD ->
 *   23 01 00 00 02 00 00 00 DE AD 00 00 00 00 00 00
 * A sample carries one frame or a batch of N frames (N x 16 bytes).
 * Golden vectors shared with the Python bench: tests/data/wire_vectors.txt. */
#ifndef ZENOH_SERIALIZE_H
#define ZENOH_SERIALIZE_H

#include <stddef.h>
#include <stdint.h>

#include "driver/can.h"

#define ZENOH_CAN_WIRE_SIZE 16
#define ZENOH_CAN_FLAG_EXTD 0x01u
#define ZENOH_CAN_FLAG_RTR 0x02u

/* Why a payload was refused; negative, grouped by cause, stable (they name
 * the counters in the bridge's stats). */
typedef enum {
	ZN_WIRE_OK = 0,
	ZN_WIRE_ERR_ARG = -1,	      /* NULL pointer or output buffer too small */
	ZN_WIRE_ERR_LENGTH = -2,      /* payload not exactly 16 bytes (or N x 16 for a batch) */
	ZN_WIRE_ERR_DLC = -3,	      /* dlc > 8 */
	ZN_WIRE_ERR_FLAGS = -4,	      /* unknown flag bits set */
	ZN_WIRE_ERR_RESERVED = -5,    /* reserved bytes 6-7 not zero */
	ZN_WIRE_ERR_ID_RANGE = -6,    /* id does not fit 11 bits (standard) or 29 bits (extended) */
	ZN_WIRE_ERR_REMOTE_DATA = -7, /* remote frame with data bytes */
	ZN_WIRE_ERR_PADDING = -8,     /* data bytes beyond dlc not zero */
} zn_wire_result_t;
#define ZN_WIRE_REASONS 9 /* counters indexed by -result */

/* Encodes msg into buf; returns 16 or -1 (bad argument or msg that is not a
 * valid CAN 2.0 frame: dlc > 8, id out of range). */
int zenoh_serialize_can_msg(const can_message_t *msg, uint8_t *buf, size_t len);

/* Decodes exactly 16 bytes; returns 0 or -1. */
int zenoh_deserialize_can_msg(const uint8_t *buf, size_t len, can_message_t *msg);

/* Like zenoh_deserialize_can_msg, with the reason for a refusal. */
zn_wire_result_t zenoh_decode_can_frame(const uint8_t *buf, size_t len, can_message_t *msg);

/* Checks every frame of a batch; msgs may be NULL to validate only. */
zn_wire_result_t zenoh_decode_can_batch(const uint8_t *buf, size_t len, can_message_t *msgs, size_t max_msgs,
					size_t *count);

/* ROS 2 can_msgs/msg/Frame in CDR (XCDR1, little endian, with the 4-byte
 * encapsulation header), as rmw_zenoh carries it: header.stamp = stamp_ns,
 * header.frame_id = frame_id, id, is_rtr, is_extended, is_error (0), dlc,
 * data[8]. Returns the length written, or -1 if buf is too small. */
int zn_ros2_encode_can_frame(const can_message_t *msg, int64_t stamp_ns, const char *frame_id, uint8_t *buf,
			     size_t len);
#define ZN_ROS2_FRAME_TYPE "can_msgs::msg::dds_::Frame_"
/* REP-2011 hash of can_msgs/msg/Frame (computed as rosidl does; canbench/ros2.py checks the method) */
#define ZN_ROS2_FRAME_HASH "RIHS01_0cdc7d15657573ee6ff151e5cc1943888301e370d957e2c077a154f4755fd976"

/* Stable lower-case name of a result ("length", "dlc", ...), for logs and stats keys. */
const char *zenoh_wire_reason(zn_wire_result_t result);

#endif
