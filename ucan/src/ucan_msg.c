/* ucan_msg.c - see ucan_msg.h. */
#include "ucan_msg.h"

#include <string.h>

const struct ucan_ifinfo *ucan_find_if(const struct ucan_ifinfo *ifs, unsigned nifs, uint32_t ifindex)
{
	for (unsigned i = 0; i < nifs; i++)
		if (ifs[i].ifindex == ifindex)
			return &ifs[i];
	return NULL;
}

static int validate_sockopts(const uint8_t *msg, size_t len, const struct ucan_ifinfo *ifs, unsigned nifs)
{
	struct ucan_sockopts opts;
	if (len < sizeof(opts))
		return UCAN_MSG_ERR_SHORT;
	memcpy(&opts, msg, sizeof(opts));
	if (opts.nfilters > UCAN_MAX_FILTERS)
		return UCAN_MSG_ERR_FILTERS;
	if (len != sizeof(opts) + (size_t)opts.nfilters * sizeof(struct can_filter))
		return UCAN_MSG_ERR_LENGTH;
	if (opts.ifindex != 0 && !ucan_find_if(ifs, nifs, opts.ifindex))
		return UCAN_MSG_ERR_IFINDEX;
	if (opts.loopback > 1 || opts.recv_own > 1 || opts.fd_frames > 1 || opts.join_filters > 1 ||
	    opts.bound || opts.header_mode || opts.timestamps > UCAN_TS_MAX || opts.pad)
		return UCAN_MSG_ERR_FLAGS;
	return (int)opts.type;
}

/* One frame of size bytes (its sender's buffer length) for interface ifindex; in_batch: one
 * record of a UCAN_MSG_FRAMES, which a bitrate= interface does not take (a batch read whole
 * would queue past the pause that holds its senders back). */
static int validate_one_frame(uint32_t ifindex, const uint8_t *data, size_t size, const struct ucan_ifinfo *ifs,
			      unsigned nifs, int in_batch)
{
	struct canfd_frame frame;
	if (size != CAN_MTU && size != CANFD_MTU)
		return UCAN_MSG_ERR_LENGTH;
	const struct ucan_ifinfo *ifi = ucan_find_if(ifs, nifs, ifindex);
	if (!ifi)
		return UCAN_MSG_ERR_IFINDEX;
	if (in_batch && ifi->bitrate)
		return UCAN_MSG_ERR_PACED;
	memset(&frame, 0, sizeof(frame));
	memcpy(&frame, data, size);
	if (size == CAN_MTU && frame.len > CAN_MAX_DLEN)
		return UCAN_MSG_ERR_FRAME;
	if (size == CANFD_MTU && (frame.len > CANFD_MAX_DLEN || ifi->mtu != CANFD_MTU))
		return UCAN_MSG_ERR_FRAME;
	return UCAN_MSG_OK;
}

static int validate_frame(const uint8_t *msg, size_t len, const struct ucan_ifinfo *ifs, unsigned nifs)
{
	struct ucan_txhdr hdr;
	if (len < sizeof(hdr))
		return UCAN_MSG_ERR_LENGTH;
	memcpy(&hdr, msg, sizeof(hdr));
	int rc = validate_one_frame(hdr.ifindex, msg + sizeof(hdr), len - sizeof(hdr), ifs, nifs, 0);
	return rc < 0 ? rc : UCAN_MSG_FRAME;
}

/* Every record is checked, and the records must fill the message exactly. */
static int validate_frames(const uint8_t *msg, size_t len, const struct ucan_ifinfo *ifs, unsigned nifs)
{
	struct ucan_txbatch batch;
	if (len < sizeof(batch))
		return UCAN_MSG_ERR_SHORT;
	memcpy(&batch, msg, sizeof(batch));
	if (batch.count == 0)
		return UCAN_MSG_ERR_LENGTH;
	size_t at = sizeof(batch);
	for (uint32_t i = 0; i < batch.count; i++) {
		struct ucan_txrec rec;
		if (len - at < sizeof(rec))
			return UCAN_MSG_ERR_LENGTH;
		memcpy(&rec, msg + at, sizeof(rec));
		at += sizeof(rec);
		if (rec.size > len - at)
			return UCAN_MSG_ERR_LENGTH;
		int rc = validate_one_frame(rec.ifindex, msg + at, rec.size, ifs, nifs, 1);
		if (rc < 0)
			return rc;
		at += rec.size;
	}
	return at == len ? UCAN_MSG_FRAMES : UCAN_MSG_ERR_LENGTH;
}

int ucan_msg_validate(const uint8_t *msg, size_t len, const struct ucan_ifinfo *ifs, unsigned nifs)
{
	uint32_t type;
	if (len < sizeof(type))
		return UCAN_MSG_ERR_SHORT;
	memcpy(&type, msg, sizeof(type));
	switch (type) {
	case UCAN_MSG_BIND:
	case UCAN_MSG_SETOPT:
		return validate_sockopts(msg, len, ifs, nifs);
	case UCAN_MSG_FRAME:
		return validate_frame(msg, len, ifs, nifs);
	case UCAN_MSG_FRAMES:
		return validate_frames(msg, len, ifs, nifs);
	case UCAN_MSG_IFLIST:
	case UCAN_MSG_STATS:
	case UCAN_MSG_RESET_STATS:
		return len == sizeof(type) ? (int)type : UCAN_MSG_ERR_LENGTH;
	case UCAN_MSG_BARRIER:
	case UCAN_MSG_GETOPT:
		if (len != sizeof(struct ucan_barrier))
			return UCAN_MSG_ERR_LENGTH;
		if (!memchr(msg + sizeof(type), '\0', UCAN_COOKIE_MAX))
			return UCAN_MSG_ERR_COOKIE;
		return (int)type;
	default:
		return UCAN_MSG_ERR_TYPE;
	}
}

const char *ucan_msg_strerror(int code)
{
	switch (code) {
	case UCAN_MSG_ERR_SHORT: return "message too short";
	case UCAN_MSG_ERR_TYPE: return "unknown message type";
	case UCAN_MSG_ERR_LENGTH: return "length does not match message type";
	case UCAN_MSG_ERR_IFINDEX: return "unknown interface index";
	case UCAN_MSG_ERR_FILTERS: return "too many filters";
	case UCAN_MSG_ERR_FRAME: return "invalid frame for interface";
	case UCAN_MSG_ERR_COOKIE: return "barrier cookie not terminated";
	case UCAN_MSG_ERR_FLAGS: return "option flag not 0 or 1, or reserved field set";
	case UCAN_MSG_ERR_PACED: return "batched frame for a bitrate= interface";
	default: return code >= 0 ? "ok" : "unknown error";
	}
}
