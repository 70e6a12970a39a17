/* zn_wire.h - the bridge's wire formats: the 16-byte CAN 2.0 frame and the
 * attachment every sample carries. One encoder and one decoder each.
 *
 * Frame, little-endian, byte by byte (no struct punning):
 *   bytes 0-3   id        u32  11-bit (extd = 0) or 29-bit (extd = 1) identifier
 *   byte  4     dlc       u8   0..8
 *   byte  5     flags     u8   bit0 extended id, bit1 remote frame, bits 2-7 = 0
 *   bytes 6-7   reserved  u16  = 0
 *   bytes 8-15  data[8]        bytes beyond dlc (all bytes of a remote frame) = 0
 * Worked example: standard id 0x123, dlc 2, data DE AD ->
 *   23 01 00 00 02 00 00 00 DE AD 00 00 00 00 00 00
 * A sample carries one frame or a batch of N frames (N x 16 bytes).
 *
 * Attachment, little-endian: version u8 (1), flags u8 (0), frame count u16,
 * sequence number of the first frame u64, then count x CAN receive time u64
 * (ns since the Unix epoch). Worked example: one frame, seq 5, rx time 1000 ->
 *   01 00 01 00 05 00 00 00 00 00 00 00 E8 03 00 00 00 00 00 00
 *
 * Golden vectors shared with the Python bench: tests/data/wire_vectors.txt. */
#ifndef ZN_WIRE_H
#define ZN_WIRE_H

#include <stddef.h>
#include <stdint.h>

#include "driver/can.h"

#define ZN_WIRE_FRAME_SIZE 16
#define ZN_WIRE_FLAG_EXTD 0x01u
#define ZN_WIRE_FLAG_RTR 0x02u

#define ZN_ATTACHMENT_VERSION 1
#define ZN_ATTACHMENT_HEADER 12
#define ZN_ATTACHMENT_SIZE(frames) (ZN_ATTACHMENT_HEADER + 8 * (size_t)(frames))

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
	ZN_WIRE_ERR_ATTACHMENT = -9,  /* attachment present but not describing the payload */
} zn_wire_result_t;
#define ZN_WIRE_REASONS 10 /* counters indexed by -result */

/* Encodes msg into buf; returns 16 or -1 (bad argument or msg that is not a
 * valid CAN 2.0 frame: dlc > 8, id out of range). */
int zn_wire_encode(const can_message_t *msg, uint8_t *buf, size_t len);

/* The one decoder: a payload of N x 16 bytes (N >= 1; a single frame is a
 * batch of one) into msgs[0..N), every frame checked. msgs may be NULL to
 * validate only; otherwise N > max_msgs is refused as length. On a refusal
 * *count is 0 and the result names the first bad frame's reason. */
zn_wire_result_t zn_wire_decode(const uint8_t *buf, size_t len, can_message_t *msgs, size_t max_msgs,
				size_t *count);

/* Writes the attachment header for `count` frames starting at `first_seq`;
 * the receive times follow with zn_attachment_set_time. buf holds at least
 * ZN_ATTACHMENT_SIZE(count) bytes. */
void zn_attachment_header(uint8_t *buf, uint16_t count, uint64_t first_seq);
void zn_attachment_set_time(uint8_t *buf, size_t index, int64_t rx_time_ns);

/* An attachment is optional on a command; if present it must describe a
 * payload of `frames` frames: ZN_WIRE_OK or ZN_WIRE_ERR_ATTACHMENT. */
zn_wire_result_t zn_attachment_check(const uint8_t *att, size_t len, size_t frames);

/* Stable lower-case name of a result ("length", "dlc", ..., "attachment"),
 * for logs and stats keys; "unknown" for anything else. */
const char *zn_wire_reason(zn_wire_result_t result);

/* ROS 2 can_msgs/msg/Frame in CDR (XCDR1, little endian, with the 4-byte
 * encapsulation header), as rmw_zenoh carries it: header.stamp = stamp_ns,
 * header.frame_id = frame_id, id, is_rtr, is_extended, is_error (0), dlc,
 * data[8]. Returns the length written, or -1 if buf is too small. */
int zn_ros2_encode_can_frame(const can_message_t *msg, int64_t stamp_ns, const char *frame_id, uint8_t *buf,
			     size_t len);
#define ZN_ROS2_FRAME_TYPE "can_msgs::msg::dds_::Frame_"
/* REP-2011 hash of can_msgs/msg/Frame (computed as rosidl does; canbench/ros2.py checks the method) */
#define ZN_ROS2_FRAME_HASH "RIHS01_0cdc7d15657573ee6ff151e5cc1943888301e370d957e2c077a154f4755fd976"

#endif
