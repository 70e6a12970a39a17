/* zn_wire.c - the wire formats' codec; see zn_wire.h for the grammar. */
#include "zn_wire.h"

#include <string.h>

static void put_le(uint8_t *p, uint64_t v, int bytes)
{
	for (int i = 0; i < bytes; i++)
		p[i] = (uint8_t)(v >> (8 * i));
}

static uint64_t get_le(const uint8_t *p, int bytes)
{
	uint64_t v = 0;
	for (int i = bytes - 1; i >= 0; i--)
		v = v << 8 | p[i];
	return v;
}

int zn_wire_encode(const can_message_t *msg, uint8_t *buf, size_t len)
{
	if (!msg || !buf || len < ZN_WIRE_FRAME_SIZE)
		return -1;
	uint32_t id_mask = msg->extd ? CAN_EXTD_ID_MASK : CAN_STD_ID_MASK;
	if (msg->data_length_code > TWAI_FRAME_MAX_DLC || (msg->identifier & ~id_mask))
		return -1;
	memset(buf, 0, ZN_WIRE_FRAME_SIZE);
	put_le(buf, msg->identifier, 4);
	buf[4] = msg->data_length_code;
	buf[5] = (uint8_t)((msg->extd ? ZN_WIRE_FLAG_EXTD : 0) | (msg->rtr ? ZN_WIRE_FLAG_RTR : 0));
	if (!msg->rtr)
		memcpy(buf + 8, msg->data, msg->data_length_code);
	return ZN_WIRE_FRAME_SIZE;
}

static zn_wire_result_t decode_frame(const uint8_t *buf, can_message_t *msg)
{
	uint32_t id = (uint32_t)get_le(buf, 4);
	uint8_t dlc = buf[4], flags = buf[5];
	if (dlc > TWAI_FRAME_MAX_DLC)
		return ZN_WIRE_ERR_DLC;
	if (flags & ~(ZN_WIRE_FLAG_EXTD | ZN_WIRE_FLAG_RTR))
		return ZN_WIRE_ERR_FLAGS;
	if (buf[6] || buf[7])
		return ZN_WIRE_ERR_RESERVED;
	int extd = !!(flags & ZN_WIRE_FLAG_EXTD), rtr = !!(flags & ZN_WIRE_FLAG_RTR);
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

zn_wire_result_t zn_wire_decode(const uint8_t *buf, size_t len, can_message_t *msgs, size_t max_msgs, size_t *count)
{
	if (!buf || !count)
		return ZN_WIRE_ERR_ARG;
	*count = 0;
	if (len == 0 || len % ZN_WIRE_FRAME_SIZE)
		return ZN_WIRE_ERR_LENGTH;
	size_t n = len / ZN_WIRE_FRAME_SIZE;
	if (msgs && n > max_msgs)
		return ZN_WIRE_ERR_LENGTH;
	for (size_t i = 0; i < n; i++) {
		zn_wire_result_t rc = decode_frame(buf + i * ZN_WIRE_FRAME_SIZE, msgs ? &msgs[i] : NULL);
		if (rc != ZN_WIRE_OK)
			return rc;
	}
	*count = n;
	return ZN_WIRE_OK;
}

void zn_attachment_header(uint8_t *buf, uint16_t count, uint64_t first_seq)
{
	buf[0] = ZN_ATTACHMENT_VERSION;
	buf[1] = 0;
	put_le(buf + 2, count, 2);
	put_le(buf + 4, first_seq, 8);
}

void zn_attachment_set_time(uint8_t *buf, size_t index, int64_t rx_time_ns)
{
	put_le(buf + ZN_ATTACHMENT_HEADER + 8 * index, (uint64_t)rx_time_ns, 8);
}

zn_wire_result_t zn_attachment_check(const uint8_t *att, size_t len, size_t frames)
{
	if (!att)
		return ZN_WIRE_OK;
	if (len < ZN_ATTACHMENT_HEADER || att[0] != ZN_ATTACHMENT_VERSION || att[1] != 0 || get_le(att + 2, 2) != frames ||
	    len != ZN_ATTACHMENT_SIZE(frames))
		return ZN_WIRE_ERR_ATTACHMENT;
	return ZN_WIRE_OK;
}

/* Indexed by -result; the stats and logs use these names. */
static const char *const reasons[ZN_WIRE_REASONS] = {
	"ok", "argument", "length", "dlc", "flags", "reserved", "id_range", "remote_data", "padding", "attachment",
};

const char *zn_wire_reason(zn_wire_result_t result)
{
	return result <= 0 && result > -ZN_WIRE_REASONS ? reasons[-result] : "unknown";
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
