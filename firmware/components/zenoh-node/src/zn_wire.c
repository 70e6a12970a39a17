/* zenoh_serialize.c - see zenoh_serialize.h for the format. */
#include "zenoh_serialize.h"

#include <string.h>

static void put_u32_le(uint8_t *p, uint32_t v)
{
	p[0] = (uint8_t)v;
	p[1] = (uint8_t)(v >> 8);
	p[2] = (uint8_t)(v >> 16);
	p[3] = (uint8_t)(v >> 24);
}

static uint32_t get_u32_le(const uint8_t *p)
{
	return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

int zenoh_serialize_can_msg(const can_message_t *msg, uint8_t *buf, size_t len)
{
	if (!msg || !buf || len < ZENOH_CAN_WIRE_SIZE)
		return -1;
	uint32_t id_mask = msg->extd ? CAN_EXTD_ID_MASK : CAN_STD_ID_MASK;
	if (msg->data_length_code > TWAI_FRAME_MAX_DLC || (msg->identifier & ~id_mask))
		return -1;
	memset(buf, 0, ZENOH_CAN_WIRE_SIZE);
	put_u32_le(buf, msg->identifier);
	buf[4] = msg->data_length_code;
	buf[5] = (uint8_t)((msg->extd ? ZENOH_CAN_FLAG_EXTD : 0) | (msg->rtr ? ZENOH_CAN_FLAG_RTR : 0));
	if (!msg->rtr)
		memcpy(buf + 8, msg->data, msg->data_length_code);
	return ZENOH_CAN_WIRE_SIZE;
}

zn_wire_result_t zenoh_decode_can_frame(const uint8_t *buf, size_t len, can_message_t *msg)
{
	if (!buf)
		return ZN_WIRE_ERR_ARG;
	if (len != ZENOH_CAN_WIRE_SIZE)
		return ZN_WIRE_ERR_LENGTH;
	uint32_t id = get_u32_le(buf);
	uint8_t dlc = buf[4], flags = buf[5];
	if (dlc > TWAI_FRAME_MAX_DLC)
		return ZN_WIRE_ERR_DLC;
	if (flags & ~(ZENOH_CAN_FLAG_EXTD | ZENOH_CAN_FLAG_RTR))
		return ZN_WIRE_ERR_FLAGS;
	if (buf[6] || buf[7])
		return ZN_WIRE_ERR_RESERVED;
	int extd = !!(flags & ZENOH_CAN_FLAG_EXTD), rtr = !!(flags & ZENOH_CAN_FLAG_RTR);
	if (id & ~(extd ? CAN_EXTD_ID_MASK : CAN_STD_ID_MASK))
		return ZN_WIRE_ERR_ID_RANGE;
	for (unsigned i = rtr ? 0 : dlc; i < TWAI_FRAME_MAX_DLC; i++)
		if (buf[8 + i])
			return rtr ? ZN_WIRE_ERR_REMOTE_DATA : ZN_WIRE_ERR_PADDING;
	if (msg) {
		memset(msg, 0, sizeof(*msg));
		msg->identifier = id;
		msg->data_length_code = dlc;
		msg->extd = (uint32_t)extd;
		msg->rtr = (uint32_t)rtr;
		memcpy(msg->data, buf + 8, TWAI_FRAME_MAX_DLC);
	}
	return ZN_WIRE_OK;
}

int zenoh_deserialize_can_msg(const uint8_t *buf, size_t len, can_message_t *msg)
{
	if (!msg)
		return -1;
	return zenoh_decode_can_frame(buf, len, msg) == ZN_WIRE_OK ? 0 : -1;
}

zn_wire_result_t zenoh_decode_can_batch(const uint8_t *buf, size_t len, can_message_t *msgs, size_t max_msgs,
					size_t *count)
{
	if (!buf || !count)
		return ZN_WIRE_ERR_ARG;
	*count = 0;
	if (len == 0 || len % ZENOH_CAN_WIRE_SIZE)
		return ZN_WIRE_ERR_LENGTH;
	size_t n = len / ZENOH_CAN_WIRE_SIZE;
	if (msgs && n > max_msgs)
		return ZN_WIRE_ERR_LENGTH;
	for (size_t i = 0; i < n; i++) {
		zn_wire_result_t rc =
			zenoh_decode_can_frame(buf + i * ZENOH_CAN_WIRE_SIZE, ZENOH_CAN_WIRE_SIZE, msgs ? &msgs[i] : NULL);
		if (rc != ZN_WIRE_OK)
			return rc;
	}
	*count = n;
	return ZN_WIRE_OK;
}

const char *zenoh_wire_reason(zn_wire_result_t result)
{
	switch (result) {
	case ZN_WIRE_OK: return "ok";
	case ZN_WIRE_ERR_ARG: return "argument";
	case ZN_WIRE_ERR_LENGTH: return "length";
	case ZN_WIRE_ERR_DLC: return "dlc";
	case ZN_WIRE_ERR_FLAGS: return "flags";
	case ZN_WIRE_ERR_RESERVED: return "reserved";
	case ZN_WIRE_ERR_ID_RANGE: return "id_range";
	case ZN_WIRE_ERR_REMOTE_DATA: return "remote_data";
	case ZN_WIRE_ERR_PADDING: return "padding";
	}
	return "unknown";
}

int zn_ros2_encode_can_frame(const can_message_t *msg, int64_t stamp_ns, const char *frame_id, uint8_t *buf,
			     size_t len)
{
	size_t id_len = strlen(frame_id) + 1; /* CDR strings carry their NUL */
	size_t pad = (4 - (8 + 4 + id_len) % 4) % 4;
	size_t need = 4 + 8 + 4 + id_len + pad + 4 + 4 + 8;
	if (!msg || !buf || len < need)
		return -1;
	uint8_t *p = buf;
	static const uint8_t encapsulation[4] = { 0x00, 0x01, 0x00, 0x00 }; /* CDR little endian */
	memcpy(p, encapsulation, 4);
	p += 4;
	int64_t sec = stamp_ns / 1000000000;
	uint32_t nsec = (uint32_t)(stamp_ns % 1000000000);
	uint32_t words[2] = { (uint32_t)(int32_t)sec, nsec };
	for (int w = 0; w < 2; w++)
		for (int i = 0; i < 4; i++)
			*p++ = (uint8_t)(words[w] >> (8 * i));
	for (int i = 0; i < 4; i++)
		*p++ = (uint8_t)(id_len >> (8 * i));
	memcpy(p, frame_id, id_len);
	p += id_len;
	memset(p, 0, pad);
	p += pad;
	for (int i = 0; i < 4; i++)
		*p++ = (uint8_t)(msg->identifier >> (8 * i));
	*p++ = msg->rtr ? 1 : 0;
	*p++ = msg->extd ? 1 : 0;
	*p++ = 0; /* is_error: the bridge never forwards error frames */
	*p++ = msg->data_length_code;
	memset(p, 0, 8);
	if (!msg->rtr)
		memcpy(p, msg->data, msg->data_length_code <= 8 ? msg->data_length_code : 8);
	p += 8;
	return (int)(p - buf);
}
