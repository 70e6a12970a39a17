/* ucan_msg.h - validation of client -> hub messages. Pure function so the
 * fuzzer exercises exactly what the hub trusts. */
#ifndef UCAN_MSG_H
#define UCAN_MSG_H

#include <stddef.h>
#include <stdint.h>
#include "ucan_proto.h"

/* Reasons a message is refused; the hub counts them and closes the sender. */
enum ucan_msg_error {
	UCAN_MSG_OK = 0,
	UCAN_MSG_ERR_SHORT = -1,	/* shorter than its type needs */
	UCAN_MSG_ERR_TYPE = -2,		/* unknown type */
	UCAN_MSG_ERR_LENGTH = -3,	/* length does not match the type's layout */
	UCAN_MSG_ERR_IFINDEX = -4,	/* no such interface */
	UCAN_MSG_ERR_FILTERS = -5,	/* filter count over CAN_RAW_FILTER_MAX */
	UCAN_MSG_ERR_FRAME = -6,	/* frame size / length invalid for the interface */
	UCAN_MSG_ERR_COOKIE = -7,	/* barrier cookie not NUL-terminated */
	UCAN_MSG_ERR_FLAGS = -8,	/* boolean option not 0/1, unknown timestamp kind, or a reserved field set */
	UCAN_MSG_ERR_PACED = -9,	/* a batch holds a frame for a bitrate= interface (those go one per message) */
};

/* Returns the message type (> 0) or an enum ucan_msg_error. */
int ucan_msg_validate(const uint8_t *msg, size_t len, const struct ucan_ifinfo *ifs, unsigned nifs);

const struct ucan_ifinfo *ucan_find_if(const struct ucan_ifinfo *ifs, unsigned nifs, uint32_t ifindex);

const char *ucan_msg_strerror(int code);

#endif
