/* can_socketcan.c - CAN port over Linux SocketCAN (kernel vcan/can, or the
 * userspace bus through libucan-preload.so). One CAN_RAW socket per bus for
 * both directions: the bridge never receives the commands it transmits, as a
 * real controller does not. */
#define _GNU_SOURCE
#include <errno.h>
#include <net/if.h>
#include <poll.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <time.h>
#include <unistd.h>
#include <linux/can.h>
#include <linux/can/raw.h>

#include "zn_port_can.h"
#include "zn_port_os.h"

#define CAN_RCVBUF_BYTES (4 << 20)
/* What one queued frame costs a socket's receive buffer at most (skb truesize: a CAN
 * frame's skb is under 1 KiB on x86-64 and arm64; the userspace hub's unix messages
 * are smaller still and the hub queues more behind them): capacity = buffer / this. */
#define CAN_FRAME_RCVBUF_COST 2048
/* ... and at most this many: on the userspace bus the socket holds only what the hub's
 * send buffer keeps in flight (net.core.wmem_default 212992 B: about 280 messages); the hub
 * queues the rest, but hands it over only as fast as the reader empties the socket, so a
 * reader that lets more wait than this falls behind (measured: 33 k frames still in the hub
 * after a 50 k frames/s load, capacity taken as 4096 from an 8 MiB SO_RCVBUF). */
#define CAN_RX_CAPACITY_MAX 256

struct zn_can {
	int fd;
	char name[IFNAMSIZ];
	size_t rx_capacity;
	/* zn_can_receive_burst's vectors: one reader per port; set up at open, and after a
	 * call only the entries it filled are reset (a call costs what it returns, not 64) */
	size_t rx_used;
	int rx_emptied; /* the last call returned less than it asked: nothing was left queued */
	int rcvtimeo_ms; /* the socket's SO_RCVTIMEO as last set (0: none) */
	struct mmsghdr mm[ZN_CAN_BURST_MAX];
	struct iovec iov[ZN_CAN_BURST_MAX];
	struct can_frame frames[ZN_CAN_BURST_MAX];
	char control[ZN_CAN_BURST_MAX][CMSG_SPACE(sizeof(struct timespec))];
};

esp_err_t zn_can_open(const char *name, zn_can_t **out)
{
	struct ifreq ifr;
	struct sockaddr_can addr = { .can_family = AF_CAN };
	zn_can_t *can = calloc(1, sizeof(*can));
	if (!can)
		return ESP_ERR_NO_MEM;
	if (strlen(name) >= sizeof(can->name)) {
		free(can);
		return ESP_ERR_INVALID_ARG;
	}
	strcpy(can->name, name);
	can->fd = socket(PF_CAN, SOCK_RAW | SOCK_CLOEXEC, CAN_RAW);
	if (can->fd < 0) {
		zn_log("E", "%s: socket(PF_CAN): %s", name, strerror(errno));
		free(can);
		return ESP_FAIL;
	}
	memset(&ifr, 0, sizeof(ifr));
	strcpy(ifr.ifr_name, name);
	int on = 1;
	if (ioctl(can->fd, SIOCGIFINDEX, &ifr) < 0) {
		zn_log("E", "%s: no such CAN interface: %s", name, strerror(errno));
		goto fail;
	}
	addr.can_ifindex = ifr.ifr_ifindex;
	/* bursts must wait in the socket, not be dropped by it (the kernel caps this at rmem_max) */
	int rcvbuf = CAN_RCVBUF_BYTES;
	setsockopt(can->fd, SOL_SOCKET, SO_RCVBUF, &rcvbuf, sizeof(rcvbuf));
	/* kernel receive timestamps: latency is measured from the moment the frame was on the bus */
	if (setsockopt(can->fd, SOL_SOCKET, SO_TIMESTAMPNS, &on, sizeof(on)) < 0 ||
	    bind(can->fd, (struct sockaddr *)&addr, sizeof(addr)) < 0) {
		zn_log("E", "%s: bind: %s", name, strerror(errno));
		goto fail;
	}
	int granted = 0;
	socklen_t len = sizeof(granted);
	if (getsockopt(can->fd, SOL_SOCKET, SO_RCVBUF, &granted, &len) < 0 || granted <= 0)
		granted = 0;
	for (size_t i = 0; i < ZN_CAN_BURST_MAX; i++) {
		can->iov[i] = (struct iovec){ .iov_base = &can->frames[i], .iov_len = sizeof(can->frames[i]) };
		can->mm[i].msg_hdr = (struct msghdr){ .msg_iov = &can->iov[i], .msg_iovlen = 1,
						      .msg_control = can->control[i],
						      .msg_controllen = sizeof(can->control[i]) };
	}
	can->rx_capacity = (size_t)granted / CAN_FRAME_RCVBUF_COST;
	if (can->rx_capacity > CAN_RX_CAPACITY_MAX)
		can->rx_capacity = CAN_RX_CAPACITY_MAX;
	if (can->rx_capacity < 1)
		can->rx_capacity = 1;
	*out = can;
	return ESP_OK;
fail:
	close(can->fd);
	free(can);
	return ESP_FAIL;
}

static void from_frame(const struct can_frame *frame, can_message_t *msg)
{
	memset(msg, 0, sizeof(*msg));
	msg->extd = !!(frame->can_id & CAN_EFF_FLAG);
	msg->rtr = !!(frame->can_id & CAN_RTR_FLAG);
	msg->identifier = frame->can_id & (msg->extd ? CAN_EFF_MASK : CAN_SFF_MASK);
	msg->data_length_code = frame->len > CAN_MAX_DLEN ? CAN_MAX_DLEN : frame->len;
	if (!msg->rtr)
		memcpy(msg->data, frame->data, msg->data_length_code);
}

static void to_frame(const can_message_t *msg, struct can_frame *frame)
{
	memset(frame, 0, sizeof(*frame));
	frame->can_id = msg->identifier | (msg->extd ? CAN_EFF_FLAG : 0) | (msg->rtr ? CAN_RTR_FLAG : 0);
	frame->len = msg->data_length_code;
	if (!msg->rtr)
		memcpy(frame->data, msg->data, msg->data_length_code);
}

/* The frame's kernel receive stamp (SO_TIMESTAMPNS, the moment it was on the bus), else fallback. */
static int64_t stamp_of(struct msghdr *mh, int64_t fallback)
{
	for (struct cmsghdr *c = CMSG_FIRSTHDR(mh); c; c = CMSG_NXTHDR(mh, c))
		if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SO_TIMESTAMPNS) {
			struct timespec ts;
			memcpy(&ts, CMSG_DATA(c), sizeof(ts));
			return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
		}
	return fallback;
}

/* How a writer waits out a full tx queue. On a real interface ENOBUFS means the device's queue
 * (txqueuelen) is full, e.g. a bus without an ACK or bus-off, and poll() says the socket is
 * writable all the while (its own buffer has room): retrying at once would spin a core until the
 * deadline. So once a send fails again right after poll said writable, the writer sleeps, 50 us
 * doubling to 1 ms. The userspace bus's poll does wait for room: it never gets that far. */
#define TX_BACKOFF_MIN_US 50
#define TX_BACKOFF_MAX_US 1000

struct tx_wait {
	int64_t deadline;  /* monotonic ns */
	int polled;	   /* the last wait was a poll that said writable */
	int backoff_us;	   /* the next sleep (0: none yet) */
};

/* The tx queue is full: waits for room until the deadline; 0 once it has passed. */
static int wait_writable(int fd, struct tx_wait *w)
{
	int64_t left_ns = w->deadline - zn_monotonic_ns();
	if (left_ns <= 0)
		return 0;
	if (w->polled) { /* poll said writable, yet the queue was still full: it cannot tell */
		w->backoff_us = w->backoff_us ? w->backoff_us * 2 : TX_BACKOFF_MIN_US;
		if (w->backoff_us > TX_BACKOFF_MAX_US)
			w->backoff_us = TX_BACKOFF_MAX_US;
		int64_t sleep_ns = (int64_t)w->backoff_us * 1000 < left_ns ? (int64_t)w->backoff_us * 1000 : left_ns;
		struct timespec ts = { .tv_sec = 0, .tv_nsec = (long)sleep_ns };
		nanosleep(&ts, NULL);
		w->polled = 0;
		return 1;
	}
	int left_ms = (int)((left_ns + 999999) / 1000000);
	struct pollfd pfd = { .fd = fd, .events = POLLOUT };
	w->polled = poll(&pfd, 1, left_ms) > 0;
	return 1;
}

static void sent_some(struct tx_wait *w, int timeout_ms)
{
	w->deadline = zn_monotonic_ns() + (int64_t)timeout_ms * 1000000; /* per frame */
	w->polled = 0;
	w->backoff_us = 0;
}

/* Sets the socket's receive timeout for the blocking read that follows (0: none, just a
 * flag on the socket; only changed when it differs from the last one set). */
static int set_receive_timeout(zn_can_t *can, int timeout_ms)
{
	if (timeout_ms < 0)
		timeout_ms = 0; /* SO_RCVTIMEO's "for ever" */
	if (timeout_ms == can->rcvtimeo_ms)
		return 0;
	struct timeval tv = { .tv_sec = timeout_ms / 1000, .tv_usec = (timeout_ms % 1000) * 1000 };
	if (setsockopt(can->fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv)) < 0)
		return -1;
	can->rcvtimeo_ms = timeout_ms;
	return 0;
}

esp_err_t zn_can_receive_burst(zn_can_t *can, zn_can_rx_t *out, size_t max, size_t *count, int timeout_ms)
{
	*count = 0;
	if (max == 0)
		return ESP_ERR_INVALID_ARG;
	if (max > ZN_CAN_BURST_MAX)
		max = ZN_CAN_BURST_MAX;
	/* Under load a burst costs one non-blocking read. After a call that emptied the socket a
	 * read now would most likely find nothing: wait in the read itself (MSG_WAITFORONE with
	 * SO_RCVTIMEO: blocks for the first frame, then takes what else is there), one syscall a
	 * wakeup where a poll and a read were two. One wait per call: a wait that brought only
	 * error frames ends the call as a timeout does, so a call never waits much beyond
	 * timeout_ms. A signal ends the wait as a timeout does (a socket with a receive timeout
	 * is never restarted): the caller comes back. */
	int wait = can->rx_emptied && timeout_ms != 0, waited = 0;
	for (;;) {
		for (size_t i = 0; i < can->rx_used; i++) /* what the last call's messages changed */
			can->mm[i].msg_hdr.msg_controllen = sizeof(can->control[i]);
		can->rx_used = 0;
		if (wait && set_receive_timeout(can, timeout_ms) < 0)
			return ESP_FAIL;
		int n = recvmmsg(can->fd, can->mm, (unsigned)max, wait ? MSG_WAITFORONE : MSG_DONTWAIT, NULL);
		waited |= wait;
		wait = 0;
		if (n > 0)
			can->rx_used = (size_t)n;
		can->rx_emptied = n < (int)max;
		if (n < 0) {
			if (errno != EAGAIN && errno != EINTR)
				return ESP_FAIL;
			if (waited || timeout_ms == 0)
				return ESP_ERR_TIMEOUT;
			wait = 1;
			continue;
		}
		int64_t now = 0;
		for (int i = 0; i < n; i++) {
			if (can->mm[i].msg_len == 0)
				return *count ? ESP_OK : ESP_FAIL; /* end of file: not a CAN socket any more */
			const struct can_frame *frame = &can->frames[i];
			if (can->mm[i].msg_len != sizeof(*frame) || (frame->can_id & CAN_ERR_FLAG))
				continue; /* error frames and anything unexpected are not bridged */
			if (!now)
				now = zn_realtime_ns(); /* a frame without a stamp: its read time */
			out[*count].rx_time_ns = stamp_of(&can->mm[i].msg_hdr, now);
			from_frame(frame, &out[*count].msg);
			(*count)++;
		}
		if (*count)
			return ESP_OK;
		if (waited && n < (int)max)
			return ESP_ERR_TIMEOUT; /* the wait brought only error frames, and nothing else is queued */
	}
}

/* One frame: a burst of one, so both calls wait the same way. */
esp_err_t zn_can_receive(zn_can_t *can, can_message_t *msg, int64_t *rx_time_ns, int timeout_ms)
{
	zn_can_rx_t rx;
	size_t n = 0;
	esp_err_t err = zn_can_receive_burst(can, &rx, 1, &n, timeout_ms);
	if (err == ESP_OK) {
		*msg = rx.msg;
		*rx_time_ns = rx.rx_time_ns;
	}
	return err;
}

size_t zn_can_rx_capacity(zn_can_t *can)
{
	return can->rx_capacity;
}

esp_err_t zn_can_send_burst(zn_can_t *can, const can_message_t *msgs, size_t n, size_t *sent, int timeout_ms)
{
	struct can_frame frames[ZN_CAN_BURST_MAX];
	struct iovec iov[ZN_CAN_BURST_MAX];
	struct mmsghdr mm[ZN_CAN_BURST_MAX];
	struct tx_wait w = { .deadline = zn_monotonic_ns() + (int64_t)timeout_ms * 1000000 };
	*sent = 0;
	while (*sent < n) {
		size_t k = n - *sent < ZN_CAN_BURST_MAX ? n - *sent : ZN_CAN_BURST_MAX;
		for (size_t i = 0; i < k; i++) {
			to_frame(&msgs[*sent + i], &frames[i]);
			iov[i] = (struct iovec){ .iov_base = &frames[i], .iov_len = sizeof(frames[i]) };
			mm[i] = (struct mmsghdr){ .msg_hdr = { .msg_iov = &iov[i], .msg_iovlen = 1 } };
		}
		int r = sendmmsg(can->fd, mm, (unsigned)k, MSG_DONTWAIT);
		if (r > 0) {
			*sent += (size_t)r;
			sent_some(&w, timeout_ms); /* the deadline per frame, as zn_can_transmit */
			continue;
		}
		if (r < 0 && errno != ENOBUFS && errno != EAGAIN)
			return ESP_FAIL;
		if (!wait_writable(can->fd, &w))
			return ESP_ERR_TIMEOUT;
	}
	return ESP_OK;
}

esp_err_t zn_can_transmit(zn_can_t *can, const can_message_t *msg, int timeout_ms)
{
	struct can_frame frame;
	to_frame(msg, &frame);
	struct tx_wait w = { .deadline = zn_monotonic_ns() + (int64_t)timeout_ms * 1000000 };
	for (;;) {
		ssize_t n = send(can->fd, &frame, sizeof(frame), MSG_DONTWAIT);
		if (n == sizeof(frame))
			return ESP_OK;
		if (n < 0 && errno != ENOBUFS && errno != EAGAIN)
			return ESP_FAIL;
		if (!wait_writable(can->fd, &w))
			return ESP_ERR_TIMEOUT;
	}
}

void zn_can_close(zn_can_t *can)
{
	if (!can)
		return;
	close(can->fd);
	free(can);
}
