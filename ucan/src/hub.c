/* hub.c - the userspace SocketCAN bus: serves virtual CAN interfaces to
 * programs running under libucan-preload.so, with kernel vcan semantics
 * (hub_main.c is the ucan-hub daemon around it, hub.h the interface).
 *
 * One thread, one epoll loop. Every frame accepted from a sender is delivered
 * to all matching readers before the next frame is read, which gives the one
 * global frame order per interface that vcan has. A reader that cannot keep
 * up gets frames queued in the hub up to its limit, then dropped and counted;
 * no reader ever blocks the bus. */
#define _GNU_SOURCE
#include <assert.h>
#include <errno.h>
#include <fcntl.h>
#include <inttypes.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/file.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/timerfd.h>
#include <sys/un.h>
#include <time.h>
#include <unistd.h>

#include "canfilter.h"
#include "hub.h"
#include "canframelen.h"
#include "ucan_msg.h"
#include "ucan_proto.h"

#define FRAMES_PER_WAKEUP 256 /* read from one sender per wakeup (other messages count 1): fairness */
#define TX_PENDING_SOFT_LIMIT 256 /* bitrate interfaces: pause senders above this */
#define RECV_BATCH 64		 /* messages read per recvmmsg */
#define FIRST_READ 8		 /* ... in a sender's first read of a wakeup (fairness: see drain_batch) */
#define FLUSH_BATCH 64		 /* messages written per sendmmsg */
#define TAG_LISTEN UINT64_MAX
#define TAG_STATS_TIMER (UINT64_MAX - 1)
#define TAG_IFACE_TIMER_BASE (UINT64_MAX - 1 - UCAN_MAX_IFACES)

struct outmsg {
	uint8_t len;
	uint8_t data[sizeof(struct ucan_rxhdr) + CANFD_MTU];
};

struct client {
	int fd; /* -1 = free slot */
	uint32_t generation;
	pid_t pid;
	char cookie[UCAN_COOKIE_MAX];
	int bound, header_mode, epollout, paused, dirty, draining;
	int reader_gone; /* the peer stopped reading (exited): what it wrote is still read */
	struct ucan_sockopts opts;
	struct can_filter *filters;
	struct outmsg *queue; /* ring, grown on demand up to queue_limit */
	uint32_t queue_cap, queue_head, queue_len, queue_limit;
	uint64_t tx_frames, rx_frames, rx_bytes, rx_drops;
	uint32_t arb_epoch;
	uint32_t frames_per_msg; /* the most one message of its last read held: sizes the next read */
};

struct pending_frame {
	uint32_t client, generation, key;
	uint8_t loopback, size;
	struct canfd_frame frame;
};

struct iface {
	struct ucan_ifinfo info;
	struct ucan_ifstats stats;
	uint64_t window_bits;
	struct timespec last_stamp; /* stamps never go back on an interface, even if the clock does */
	/* bitrate emulation */
	int timerfd;
	struct pending_frame *pending;
	uint32_t npending, pending_cap;
	int on_wire; /* index into pending of the frame being transmitted, -1 if idle */
	struct timespec wire_end;
};

static struct {
	const char *dir;
	char sock_path[sizeof(((struct sockaddr_un *)0)->sun_path)];
	int listen_fd, lock_fd, epoll_fd, stats_timer_fd, verbose;
	int spare_fd;	      /* kept open to refuse connections when out of descriptors */
	int listen_paused;    /* accept failed otherwise: resumed by the stats tick */
	uint64_t refusal_logged_ns;
	unsigned spin_us; /* -s: keep polling this long after the last event before sleeping */
	uint32_t default_queue;
	struct iface ifaces[UCAN_MAX_IFACES];
	struct ucan_ifinfo ifinfos[UCAN_MAX_IFACES]; /* the same, in the layout the validator takes */
	unsigned nifs;
	struct client *clients;
	uint32_t nclients_alloc;
	uint32_t arb_epoch;
	uint32_t *dirty; /* clients with queued messages to flush this round */
	uint32_t ndirty;
	struct timespec start;
	struct ucan_hubstats counters;
	volatile sig_atomic_t stop;
} hub = { .listen_fd = -1, .lock_fd = -1, .spare_fd = -1, .epoll_fd = -1, .stats_timer_fd = -1, .default_queue = HUB_DEFAULT_QUEUE_FRAMES };

void hub_log(const char *fmt, ...)
{
	va_list ap;
	if (hub.verbose < 0) /* the fuzzer's hub: thousands of refusals a second */
		return;
	va_start(ap, fmt);
	fputs("ucan-hub: ", stderr);
	vfprintf(stderr, fmt, ap);
	fputc('\n', stderr);
	va_end(ap);
}

static uint64_t now_ns(void)
{
	struct timespec ts;
	clock_gettime(CLOCK_MONOTONIC, &ts);
	return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

void hub_request_stop(void)
{
	hub.stop = 1;
}

static void ts_add_ns(struct timespec *ts, uint64_t ns)
{
	uint64_t total = (uint64_t)ts->tv_nsec + ns;
	ts->tv_sec += (time_t)(total / 1000000000u);
	ts->tv_nsec = (long)(total % 1000000000u);
}

static int ts_before_eq(const struct timespec *a, const struct timespec *b)
{
	return a->tv_sec < b->tv_sec || (a->tv_sec == b->tv_sec && a->tv_nsec <= b->tv_nsec);
}

/* ---- configuration ---- */

int hub_add_iface(const char *spec)
{
	struct iface *ifc;
	char buf[256], *opts, *tok, *save = NULL;

	if (hub.nifs >= UCAN_MAX_IFACES) {
		hub_log("too many interfaces (max %d)", UCAN_MAX_IFACES);
		return -1;
	}
	if (snprintf(buf, sizeof(buf), "%s", spec) >= (int)sizeof(buf)) {
		hub_log("interface spec too long: %s", spec);
		return -1;
	}
	ifc = &hub.ifaces[hub.nifs];
	memset(ifc, 0, sizeof(*ifc));
	ifc->timerfd = -1;
	ifc->on_wire = -1;
	opts = strchr(buf, ':');
	if (opts)
		*opts++ = '\0';
	if (buf[0] == '\0' || strlen(buf) >= sizeof(ifc->info.name) || strchr(buf, '/')) {
		hub_log("invalid interface name '%s' (1-15 characters, no '/')", buf);
		return -1;
	}
	for (unsigned i = 0; i < hub.nifs; i++)
		if (strcmp(hub.ifaces[i].info.name, buf) == 0) {
			hub_log("interface %s given twice", buf);
			return -1;
		}
	strcpy(ifc->info.name, buf);
	ifc->info.ifindex = UCAN_IFINDEX_BASE + hub.nifs;
	ifc->info.mtu = CANFD_MTU;
	ifc->info.stuffing = UCAN_STUFF_WORST;
	for (tok = opts ? strtok_r(opts, ",", &save) : NULL; tok; tok = strtok_r(NULL, ",", &save)) {
		char *val = strchr(tok, '='), *end;
		if (!val) {
			hub_log("%s: option '%s' needs a value", ifc->info.name, tok);
			return -1;
		}
		*val++ = '\0';
		if (strcmp(tok, "bitrate") == 0) {
			unsigned long rate = strtoul(val, &end, 10);
			if (*end || rate > 10000000ul) {
				hub_log("%s: bitrate '%s' is not 0..10000000 bit/s", ifc->info.name, val);
				return -1;
			}
			ifc->info.bitrate = (uint32_t)rate;
		} else if (strcmp(tok, "stuffing") == 0) {
			if (strcmp(val, "worst") == 0)
				ifc->info.stuffing = UCAN_STUFF_WORST;
			else if (strcmp(val, "exact") == 0)
				ifc->info.stuffing = UCAN_STUFF_EXACT;
			else if (strcmp(val, "none") == 0)
				ifc->info.stuffing = UCAN_STUFF_NONE;
			else {
				hub_log("%s: stuffing '%s' is not worst|exact|none", ifc->info.name, val);
				return -1;
			}
		} else if (strcmp(tok, "mtu") == 0) {
			if (strcmp(val, "16") == 0)
				ifc->info.mtu = CAN_MTU;
			else if (strcmp(val, "72") == 0)
				ifc->info.mtu = CANFD_MTU;
			else {
				hub_log("%s: mtu '%s' is not 16 or 72", ifc->info.name, val);
				return -1;
			}
		} else {
			hub_log("%s: unknown option '%s' (bitrate, stuffing, mtu)", ifc->info.name, tok);
			return -1;
		}
	}
	hub.nifs++;
	return 0;
}

static struct iface *find_iface(uint32_t ifindex)
{
	if (ifindex < UCAN_IFINDEX_BASE || ifindex - UCAN_IFINDEX_BASE >= hub.nifs)
		return NULL;
	return &hub.ifaces[ifindex - UCAN_IFINDEX_BASE];
}

/* ---- epoll helpers ---- */

/* Tags: clients are (generation << 32 | slot) so an event queued for a client
 * closed earlier in the same batch never reaches the slot's next owner. */
static int epoll_set(int fd, uint32_t events, uint64_t tag, int op)
{
	struct epoll_event ev = { .events = events, .data.u64 = tag };
	return epoll_ctl(hub.epoll_fd, op, fd, &ev);
}

static void client_update_events(struct client *c, uint32_t idx)
{
	uint32_t events = (c->paused ? 0 : EPOLLIN) | (c->epollout ? EPOLLOUT : 0);
	epoll_set(c->fd, events, (uint64_t)c->generation << 32 | idx, EPOLL_CTL_MOD);
}

/* ---- clients ---- */

static void client_close(uint32_t idx, const char *why)
{
	struct client *c = &hub.clients[idx];
	if (c->fd < 0)
		return;
	if (hub.verbose || why || c->rx_drops) { /* a reader's drops said once it is gone: its counters go with it */
		char drops[64] = "";
		if (c->rx_drops)
			snprintf(drops, sizeof(drops), "; %" PRIu64 " frames dropped for it (queue full)", c->rx_drops);
		hub_log("client %u (pid %d, %s) closed%s%s%s", idx, (int)c->pid, c->cookie[0] ? c->cookie : "-",
			why ? ": " : "", why ? why : "", drops);
	}
	epoll_ctl(hub.epoll_fd, EPOLL_CTL_DEL, c->fd, NULL);
	close(c->fd);
	free(c->filters);
	free(c->queue);
	uint32_t generation = c->generation + 1;
	/* a slot on the flush list stays there until flush_dirty: a client that
	 * reuses the slot in the same round must not be listed a second time */
	int dirty = c->dirty;
	memset(c, 0, sizeof(*c));
	c->fd = -1;
	c->generation = generation;
	c->dirty = dirty;
}

static uint32_t client_alloc(void)
{
	for (uint32_t i = 0; i < hub.nclients_alloc; i++)
		if (hub.clients[i].fd < 0)
			return i;
	uint32_t old = hub.nclients_alloc, grown = old ? old * 2 : 64;
	struct client *clients = realloc(hub.clients, grown * sizeof(*clients));
	if (!clients)
		return UINT32_MAX;
	uint32_t *dirty = realloc(hub.dirty, grown * sizeof(*dirty));
	if (!dirty)
		return UINT32_MAX;
	hub.dirty = dirty;
	hub.clients = clients;
	for (uint32_t i = old; i < grown; i++) {
		memset(&clients[i], 0, sizeof(clients[i]));
		clients[i].fd = -1;
	}
	hub.nclients_alloc = grown;
	return old;
}

/* Out of descriptors, a pending connection would keep the (level-triggered)
 * listening socket readable forever: accept it on the spare descriptor and
 * close it at once, so the client sees the hub hang up rather than wait. */
static int refuse_connection(int err)
{
	if (hub.spare_fd < 0)
		return -1;
	close(hub.spare_fd);
	int fd = accept4(hub.listen_fd, NULL, NULL, SOCK_CLOEXEC);
	if (fd >= 0)
		close(fd);
	hub.spare_fd = open("/dev/null", O_RDONLY | O_CLOEXEC);
	if (fd < 0)
		return -1;
	hub.counters.refused_connections++;
	uint64_t now = now_ns();
	if (now - hub.refusal_logged_ns >= 1000000000u || !hub.refusal_logged_ns) { /* one line a second at most */
		hub.refusal_logged_ns = now;
		hub_log("refusing connections: %s (%" PRIu64 " refused so far)", strerror(err),
			hub.counters.refused_connections);
	}
	return 0;
}

/* Any other accept failure that would repeat (ENOBUFS, ENOMEM, no spare
 * descriptor): stop listening until the next stats tick, a second. */
static void pause_listening(int err)
{
	if (hub.listen_paused)
		return;
	hub_log("accept: %s: not accepting connections for a second", strerror(err));
	hub.listen_paused = 1;
	epoll_set(hub.listen_fd, 0, TAG_LISTEN, EPOLL_CTL_MOD);
}

static void accept_clients(void)
{
	for (;;) {
		struct sockaddr_un addr;
		socklen_t addrlen = sizeof(addr);
		int fd = accept4(hub.listen_fd, (struct sockaddr *)&addr, &addrlen, SOCK_NONBLOCK | SOCK_CLOEXEC);
		if (fd < 0) {
			int err = errno;
			if (err == EAGAIN || err == EINTR || err == ECONNABORTED)
				return;
			if ((err == EMFILE || err == ENFILE) && refuse_connection(err) == 0)
				continue;
			pause_listening(err);
			return;
		}
		uint32_t idx = client_alloc();
		if (idx == UINT32_MAX) {
			hub_log("out of memory for client");
			close(fd);
			continue;
		}
		struct client *c = &hub.clients[idx];
		c->fd = fd;
		c->queue_limit = hub.default_queue;
		c->opts.loopback = 1;
		/* the abstract name the preload library bound to, after the leading NUL */
		size_t path_len = addrlen > offsetof(struct sockaddr_un, sun_path)
					  ? addrlen - offsetof(struct sockaddr_un, sun_path)
					  : 0;
		if (path_len > 1 && addr.sun_path[0] == '\0') {
			size_t n = path_len - 1 < UCAN_COOKIE_MAX - 1 ? path_len - 1 : UCAN_COOKIE_MAX - 1;
			memcpy(c->cookie, addr.sun_path + 1, n);
		}
		struct ucred cred;
		socklen_t credlen = sizeof(cred);
		if (getsockopt(fd, SOL_SOCKET, SO_PEERCRED, &cred, &credlen) == 0)
			c->pid = cred.pid;
		if (epoll_set(fd, EPOLLIN, (uint64_t)c->generation << 32 | idx, EPOLL_CTL_ADD) < 0) {
			hub_log("epoll add: %s", strerror(errno));
			client_close(idx, "epoll failure");
			continue;
		}
		if (hub.verbose)
			hub_log("client %u connected (pid %d, %s)", idx, (int)c->pid, c->cookie);
	}
}

static int client_queue_grow(struct client *c, uint32_t cap)
{
	struct outmsg *q = malloc(cap * sizeof(*q));
	if (!q)
		return -1;
	for (uint32_t i = 0; i < c->queue_len; i++)
		q[i] = c->queue[(c->queue_head + i) % c->queue_cap];
	free(c->queue);
	c->queue = q;
	c->queue_cap = cap;
	c->queue_head = 0;
	return 0;
}

enum send_result { QUEUED, DROPPED, NO_MEMORY, READER_GONE };
enum send_kind { FRAME, CONTROL };

/* Queues a message for a client; queues are flushed once per event-loop
 * round with sendmmsg (flush_dirty), so a burst costs one syscall per reader
 * instead of one per frame. Frames are dropped at the reader's limit; control
 * messages may go UCAN_CTL_RESERVE past it (losing one would make the client
 * lose track of the stream), then the client is not reading at all. */
static enum send_result client_send(uint32_t idx, const void *msg, size_t len, enum send_kind kind)
{
	struct client *c = &hub.clients[idx];
	uint32_t limit = c->queue_limit + (kind == CONTROL ? UCAN_CTL_RESERVE : 0);
	if (c->reader_gone)
		return READER_GONE;
	if (c->queue_len >= limit)
		return DROPPED;
	if (c->queue_len == c->queue_cap) {
		uint32_t cap = c->queue_cap ? c->queue_cap * 2 : 64;
		if (cap > c->queue_limit + UCAN_CTL_RESERVE)
			cap = c->queue_limit + UCAN_CTL_RESERVE;
		if (client_queue_grow(c, cap) < 0)
			return NO_MEMORY;
	}
	struct outmsg *m = &c->queue[(c->queue_head + c->queue_len++) % c->queue_cap];
	m->len = (uint8_t)len;
	memcpy(m->data, msg, len);
	if (!c->dirty) {
		assert(hub.ndirty < hub.nclients_alloc); /* one entry per slot at most */
		c->dirty = 1;
		hub.dirty[hub.ndirty++] = idx;
	}
	return QUEUED;
}

static void client_send_ctl(uint32_t idx, uint32_t type, int status)
{
	struct ucan_ctl ctl = { .type = type, .status = status };
	if (hub.clients[idx].fd < 0)
		return;
	switch (client_send(idx, &ctl, sizeof(ctl), CONTROL)) {
	case QUEUED:
	case READER_GONE:
		break;
	case DROPPED:
		hub.counters.unread_closes++;
		client_close(idx, "does not read its replies");
		break;
	case NO_MEMORY:
		client_close(idx, "out of memory");
		break;
	}
}

/* A program that exited (or shut its socket) can still have frames in the
 * socket it wrote that the hub had not read yet: a paused sender on a
 * bitrate= interface always has. Closing it on the first failed write to it,
 * or on the ECONNRESET its exit with unread frames for it leaves (reported
 * once, before the data), lost them: accepted by its write(), never on the
 * bus. So stop writing to it, drop what was queued for it (nobody will read
 * it), and keep reading until EOF (EPOLLHUP drains a paused sender too). */
static void client_reader_gone(uint32_t idx)
{
	struct client *c = &hub.clients[idx];
	c->reader_gone = 1;
	free(c->queue);
	c->queue = NULL;
	c->queue_cap = c->queue_head = c->queue_len = 0;
	if (c->epollout) {
		c->epollout = 0;
		client_update_events(c, idx);
	}
}

static void client_send_failed(uint32_t idx, const char *why)
{
	if (errno == EPIPE || errno == ECONNRESET || errno == ECONNREFUSED || errno == ENOTCONN)
		client_reader_gone(idx);
	else
		client_close(idx, why);
}

static void client_flush(uint32_t idx)
{
	struct client *c = &hub.clients[idx];
	struct mmsghdr msgs[FLUSH_BATCH];
	struct iovec iovs[FLUSH_BATCH];
	while (c->fd >= 0 && c->queue_len > 0) {
		unsigned n = 0;
		for (; n < FLUSH_BATCH && n < c->queue_len; n++) {
			struct outmsg *m = &c->queue[(c->queue_head + n) % c->queue_cap];
			iovs[n] = (struct iovec){ .iov_base = m->data, .iov_len = m->len };
			msgs[n] = (struct mmsghdr){ .msg_hdr = { .msg_iov = &iovs[n], .msg_iovlen = 1 } };
		}
		int sent = sendmmsg(c->fd, msgs, n, MSG_DONTWAIT | MSG_NOSIGNAL);
		if (sent < 0) {
			if (errno == EAGAIN || errno == ENOBUFS)
				break;
			client_send_failed(idx, NULL);
			return;
		}
		c->queue_head = (c->queue_head + (uint32_t)sent) % c->queue_cap;
		c->queue_len -= (uint32_t)sent;
		if ((unsigned)sent < n)
			break; /* socket full: wait for EPOLLOUT */
	}
	if (c->fd < 0)
		return;
	int want_out = c->queue_len > 0;
	if (want_out != c->epollout) {
		c->epollout = want_out;
		client_update_events(c, idx);
	}
}

static void flush_dirty(void)
{
	for (uint32_t i = 0; i < hub.ndirty; i++) {
		uint32_t idx = hub.dirty[i];
		if (idx < hub.nclients_alloc && hub.clients[idx].dirty) {
			hub.clients[idx].dirty = 0;
			if (hub.clients[idx].fd >= 0)
				client_flush(idx);
		}
	}
	hub.ndirty = 0;
}

/* ---- the bus ---- */

/* The one stamp of a frame, taken as it goes on the bus: every reader (the
 * sender's echo included) gets it, as every socket does from kernel vcan.
 * A bitrate interface stamps the moment the frame left the wire (wire_end,
 * monotonic), not the moment the hub got round to it: a hub woken late
 * delivers a backlog at once, and stamps of "now" would squeeze the bus's
 * timing out of the trace. */
static struct timespec bus_stamp(struct iface *ifc, const struct timespec *wire_end)
{
	struct timespec now;
	clock_gettime(CLOCK_REALTIME, &now);
	if (wire_end) {
		struct timespec mono;
		clock_gettime(CLOCK_MONOTONIC, &mono);
		int64_t late_ns = (int64_t)(mono.tv_sec - wire_end->tv_sec) * 1000000000 +
				  (mono.tv_nsec - wire_end->tv_nsec);
		if (late_ns > 0) {
			int64_t ns = (int64_t)now.tv_sec * 1000000000 + now.tv_nsec - late_ns;
			now.tv_sec = (time_t)(ns / 1000000000);
			now.tv_nsec = (long)(ns % 1000000000);
		}
	}
	if (ts_before_eq(&now, &ifc->last_stamp))
		now = ifc->last_stamp; /* the clock was set back: hold, never decrease */
	ifc->last_stamp = now;
	return now;
}

static void deliver_to(uint32_t idx, struct iface *ifc, const struct canfd_frame *frame, size_t size, int own,
		       const struct timespec *stamp)
{
	struct client *c = &hub.clients[idx];
	uint8_t msg[sizeof(struct ucan_rxhdr) + CANFD_MTU];
	size_t len = 0;

	if (c->header_mode) {
		struct ucan_rxhdr hdr = { .ifindex = ifc->info.ifindex, .flags = own ? UCAN_RX_OWN : 0,
					  .stamp_sec = (uint64_t)stamp->tv_sec, .stamp_nsec = (uint32_t)stamp->tv_nsec };
		memcpy(msg, &hdr, sizeof(hdr));
		len = sizeof(hdr);
	}
	memcpy(msg + len, frame, size);
	len += size;

	enum send_result sent = client_send(idx, msg, len, FRAME);
	if (sent == QUEUED) {
		c->rx_frames++;
		c->rx_bytes += frame->len;
		ifc->stats.rx_deliveries++;
	} else if (sent != READER_GONE) { /* a reader that exited is not a drop */
		c->rx_drops++;
		ifc->stats.rx_drops++;
	}
}

/* A frame has been transmitted on ifc: account for it and hand it to every reader. */
static void bus_transmit(struct iface *ifc, uint32_t sender, uint32_t sender_gen, int loopback,
			 const struct canfd_frame *frame, size_t size, const struct timespec *wire_end)
{
	unsigned bits = can_frame_bits(frame, size == CANFD_MTU, (enum ucan_stuffing)ifc->info.stuffing);
	ifc->stats.frames++;
	ifc->stats.bytes += frame->len;
	ifc->stats.bits += bits;
	ifc->window_bits += bits;
	if (sender < hub.nclients_alloc && hub.clients[sender].fd >= 0 &&
	    hub.clients[sender].generation == sender_gen)
		hub.clients[sender].tx_frames++;
	/* vcan without echo loops frames back only when the sender asked for loopback;
	 * with loopback off nobody on this host sees the frame, the sender included */
	if (!loopback)
		return;
	struct timespec stamp = bus_stamp(ifc, wire_end);
	for (uint32_t i = 0; i < hub.nclients_alloc; i++) {
		struct client *c = &hub.clients[i];
		if (c->fd < 0 || !c->bound)
			continue;
		if (c->opts.ifindex != 0 && c->opts.ifindex != ifc->info.ifindex)
			continue;
		int own = (i == sender && c->generation == sender_gen);
		if (own && !c->opts.recv_own)
			continue;
		if (size == CANFD_MTU && !c->opts.fd_frames)
			continue;
		if (!can_raw_accepts(frame->can_id, c->filters, c->opts.nfilters, c->opts.err_mask,
				     c->opts.join_filters))
			continue;
		deliver_to(i, ifc, frame, size, own, &stamp);
	}
}

/* Bitrate interfaces: pick the next frame by arbitration among the oldest
 * pending frame of each sender (each node's controller sends in order). */
static int arbitrate(struct iface *ifc)
{
	int best = -1;
	hub.arb_epoch++;
	for (uint32_t i = 0; i < ifc->npending; i++) {
		struct pending_frame *p = &ifc->pending[i];
		if (p->client < hub.nclients_alloc) {
			struct client *c = &hub.clients[p->client];
			if (c->arb_epoch == hub.arb_epoch)
				continue; /* not the head of its sender's queue */
			c->arb_epoch = hub.arb_epoch;
		}
		if (best < 0 || p->key < ifc->pending[best].key)
			best = (int)i;
	}
	return best;
}

static void wire_start(struct iface *ifc, const struct timespec *start)
{
	ifc->on_wire = arbitrate(ifc);
	if (ifc->on_wire < 0)
		return;
	struct pending_frame *p = &ifc->pending[ifc->on_wire];
	unsigned bits = can_frame_bits(&p->frame, p->size == CANFD_MTU, (enum ucan_stuffing)ifc->info.stuffing);
	ifc->wire_end = *start;
	ts_add_ns(&ifc->wire_end, (uint64_t)bits * 1000000000u / ifc->info.bitrate);
	struct itimerspec its = { .it_value = ifc->wire_end };
	timerfd_settime(ifc->timerfd, TFD_TIMER_ABSTIME, &its, NULL);
}

static void unpause_senders(void)
{
	for (uint32_t i = 0; i < hub.nclients_alloc; i++) {
		struct client *c = &hub.clients[i];
		if (c->fd >= 0 && c->paused) {
			c->paused = 0;
			client_update_events(c, i);
		}
	}
}

static void wire_timer(struct iface *ifc)
{
	uint64_t expirations;
	struct timespec now;
	if (read(ifc->timerfd, &expirations, sizeof(expirations)) < 0 && errno == EAGAIN)
		return;
	clock_gettime(CLOCK_MONOTONIC, &now);
	/* catch up if the hub was late: frames follow each other back to back */
	while (ifc->on_wire >= 0 && ts_before_eq(&ifc->wire_end, &now)) {
		struct pending_frame p = ifc->pending[ifc->on_wire];
		memmove(&ifc->pending[ifc->on_wire], &ifc->pending[ifc->on_wire + 1],
			(ifc->npending - (uint32_t)ifc->on_wire - 1) * sizeof(p));
		ifc->npending--;
		ifc->on_wire = -1;
		struct timespec end = ifc->wire_end;
		bus_transmit(ifc, p.client, p.generation, p.loopback, &p.frame, p.size, &end);
		if (ifc->npending > 0)
			wire_start(ifc, &end);
	}
	if (ifc->npending < TX_PENDING_SOFT_LIMIT / 2)
		unpause_senders();
}

static int queue_for_wire(struct iface *ifc, uint32_t idx, const struct canfd_frame *frame, size_t size)
{
	struct client *c = &hub.clients[idx];
	if (ifc->npending == ifc->pending_cap) {
		uint32_t cap = ifc->pending_cap ? ifc->pending_cap * 2 : TX_PENDING_SOFT_LIMIT * 2;
		struct pending_frame *p = realloc(ifc->pending, cap * sizeof(*p));
		if (!p)
			return -1;
		ifc->pending = p;
		ifc->pending_cap = cap;
	}
	struct pending_frame *p = &ifc->pending[ifc->npending++];
	memset(p, 0, sizeof(*p));
	p->client = idx;
	p->generation = c->generation;
	p->key = can_arbitration_key(frame->can_id);
	p->loopback = c->opts.loopback;
	p->size = (uint8_t)size;
	memcpy(&p->frame, frame, size);
	if (ifc->on_wire < 0) {
		struct timespec now;
		clock_gettime(CLOCK_MONOTONIC, &now);
		wire_start(ifc, &now);
	}
	/* like a full TX queue: the sender waits (backpressure), nobody loses frames */
	if (ifc->npending >= TX_PENDING_SOFT_LIMIT && !c->paused) {
		c->paused = 1;
		client_update_events(c, idx);
	}
	return 0;
}

/* ---- client messages ---- */

static void apply_sockopts(uint32_t idx, const uint8_t *msg, size_t len)
{
	struct client *c = &hub.clients[idx];
	struct ucan_sockopts opts;
	memcpy(&opts, msg, sizeof(opts));
	struct can_filter *filters = NULL;
	if (opts.nfilters) {
		filters = malloc(opts.nfilters * sizeof(*filters));
		if (!filters) {
			client_close(idx, "out of memory");
			return;
		}
		memcpy(filters, msg + sizeof(opts), len - sizeof(opts));
	}
	free(c->filters);
	c->filters = filters;
	c->opts = opts;
	uint32_t limit = hub.default_queue, rcvbuf = opts.rcvbuf < UCAN_MAX_RCVBUF ? opts.rcvbuf : UCAN_MAX_RCVBUF;
	if (rcvbuf / CANFD_MTU > limit)
		limit = rcvbuf / CANFD_MTU;
	c->queue_limit = limit;
}

static int needs_header(const struct client *c)
{
	return c->opts.ifindex == 0 || c->opts.recv_own || c->opts.timestamps;
}

static void handle_stats(uint32_t idx)
{
	uint32_t nclients = 0;
	for (uint32_t i = 0; i < hub.nclients_alloc && nclients < UCAN_STATS_MAX_CLIENTS; i++)
		nclients += hub.clients[i].fd >= 0;
	size_t size = sizeof(struct ucan_stats) + nclients * sizeof(struct ucan_clientstats);
	struct ucan_stats *st = calloc(1, size);
	if (!st) {
		client_close(idx, "out of memory");
		return;
	}
	struct timespec now;
	clock_gettime(CLOCK_MONOTONIC, &now);
	st->type = UCAN_MSG_STATS;
	st->nifs = hub.nifs;
	st->hub = hub.counters;
	st->uptime_ms = (uint64_t)(now.tv_sec - hub.start.tv_sec) * 1000u +
			(uint64_t)((now.tv_nsec - hub.start.tv_nsec) / 1000000);
	for (unsigned i = 0; i < hub.nifs; i++) {
		st->ifs[i] = hub.ifaces[i].info;
		st->ifstats[i] = hub.ifaces[i].stats;
	}
	uint32_t n = 0;
	for (uint32_t i = 0; i < hub.nclients_alloc && n < nclients; i++) {
		struct client *c = &hub.clients[i];
		if (c->fd < 0)
			continue;
		struct ucan_clientstats *cs = &st->clients[n++];
		memcpy(cs->cookie, c->cookie, sizeof(cs->cookie));
		cs->pid = c->pid;
		cs->ifindex = c->opts.ifindex;
		cs->bound = (uint32_t)c->bound;
		cs->queued = c->queue_len;
		cs->queue_limit = c->queue_limit;
		cs->tx_frames = c->tx_frames;
		cs->rx_frames = c->rx_frames;
		cs->rx_bytes = c->rx_bytes;
		cs->rx_drops = c->rx_drops;
	}
	st->nclients = n;
	if (!hub.clients[idx].reader_gone && send(hub.clients[idx].fd, st, size, MSG_DONTWAIT | MSG_NOSIGNAL) < 0)
		client_send_failed(idx, "stats reply failed");
	free(st);
}

static void drain_client(uint32_t idx, unsigned budget, int even_if_paused);
static int can_drain_nested(uint32_t idx);

/* Settings of the connection named by a cookie: lets a program that inherited
 * an emulated socket across exec pick it up where its parent left it. */
static void handle_getopt(uint32_t idx, const uint8_t *msg)
{
	struct ucan_barrier query;
	uint8_t reply[sizeof(struct ucan_sockopts) + UCAN_MAX_FILTERS * sizeof(struct can_filter)];
	struct ucan_sockopts opts;
	size_t len = 0;

	memcpy(&query, msg, sizeof(query));
	for (uint32_t i = 0; i < hub.nclients_alloc; i++) {
		struct client *c = &hub.clients[i];
		if (i == idx || c->fd < 0 || strcmp(c->cookie, query.cookie) != 0)
			continue;
		opts = c->opts;
		opts.type = UCAN_MSG_GETOPT;
		opts.bound = (uint8_t)c->bound;
		opts.header_mode = (uint8_t)c->header_mode;
		if (c->opts.nfilters) /* an unbound client has none (NULL) */
			memcpy(reply + sizeof(opts), c->filters, c->opts.nfilters * sizeof(struct can_filter));
		len = sizeof(opts) + c->opts.nfilters * sizeof(struct can_filter);
		break;
	}
	if (len == 0) {
		client_send_ctl(idx, UCAN_MSG_ACK, ENOENT);
		return;
	}
	memcpy(reply, &opts, sizeof(opts));
	if (!hub.clients[idx].reader_gone && send(hub.clients[idx].fd, reply, len, MSG_DONTWAIT | MSG_NOSIGNAL) < 0)
		client_send_failed(idx, "getopt reply failed");
}

/* One frame a client sent (validated): on the wire now, or queued for it. */
static void transmit_from(uint32_t idx, uint32_t ifindex, const uint8_t *data, size_t size)
{
	struct client *c = &hub.clients[idx];
	struct canfd_frame frame;
	memset(&frame, 0, sizeof(frame));
	memcpy(&frame, data, size);
	/* linux >= 6.0 marks every CAN FD frame it sends (af_can.c can_send) */
	if (size == CANFD_MTU)
		frame.flags |= CANFD_FDF;
	struct iface *ifc = find_iface(ifindex);
	if (ifc->info.bitrate) {
		if (queue_for_wire(ifc, idx, &frame, size) < 0)
			ifc->stats.tx_rejects++;
	} else {
		bus_transmit(ifc, idx, c->generation, c->opts.loopback, &frame, size, NULL);
	}
}

/* Returns how many frames the message held (1 for any other message): what the
 * per-wakeup fairness budget counts. */
static unsigned handle_message(uint32_t idx, const uint8_t *msg, size_t len)
{
	struct client *c = &hub.clients[idx];
	int type = ucan_msg_validate(msg, len, hub.ifinfos, hub.nifs);
	if (type < 0) {
		hub.counters.proto_errors++;
		client_close(idx, ucan_msg_strerror(type));
		return 1;
	}
	switch (type) {
	case UCAN_MSG_BIND:
		if (c->bound) {
			hub.counters.proto_errors++;
			client_close(idx, "second BIND");
			return 1;
		}
		apply_sockopts(idx, msg, len);
		if (hub.clients[idx].fd < 0)
			return 1;
		c->bound = 1;
		c->header_mode = needs_header(c);
		client_send_ctl(idx, UCAN_MSG_ACK, 0);
		break;
	case UCAN_MSG_SETOPT:
		apply_sockopts(idx, msg, len);
		if (hub.clients[idx].fd < 0)
			return 1;
		/* no notice of the switch on the data socket: the library tells a headed frame
		 * from a bare one by its length, and a control message there would be the one
		 * message a MSG_PEEK must consume, racing a second reader of the socket for it */
		if (c->bound && !c->header_mode && needs_header(c))
			c->header_mode = 1;
		break;
	case UCAN_MSG_FRAME: {
		struct ucan_txhdr hdr;
		memcpy(&hdr, msg, sizeof(hdr));
		transmit_from(idx, hdr.ifindex, msg + sizeof(hdr), len - sizeof(hdr));
		break;
	}
	case UCAN_MSG_FRAMES: {
		struct ucan_txbatch batch;
		memcpy(&batch, msg, sizeof(batch));
		size_t at = sizeof(batch);
		uint32_t generation = c->generation;
		/* a delivery that closes the sender (its own queue overrun) ends the batch */
		for (uint32_t i = 0; i < batch.count && c->fd >= 0 && c->generation == generation; i++) {
			struct ucan_txrec rec;
			memcpy(&rec, msg + at, sizeof(rec));
			at += sizeof(rec);
			transmit_from(idx, rec.ifindex, msg + at, rec.size);
			at += rec.size;
		}
		return batch.count;
	}
	case UCAN_MSG_IFLIST: {
		struct ucan_iflist list = { .type = UCAN_MSG_IFLIST, .count = hub.nifs };
		memcpy(list.ifs, hub.ifinfos, hub.nifs * sizeof(hub.ifinfos[0]));
		if (!c->reader_gone && send(c->fd, &list, sizeof(list), MSG_DONTWAIT | MSG_NOSIGNAL) < 0)
			client_send_failed(idx, "iflist reply failed");
		break;
	}
	case UCAN_MSG_BARRIER: {
		struct ucan_barrier barrier;
		memcpy(&barrier, msg, sizeof(barrier));
		for (uint32_t i = 0; i < hub.nclients_alloc; i++) {
			if (i == idx || hub.clients[i].fd < 0 || strcmp(hub.clients[i].cookie, barrier.cookie) != 0)
				continue;
			if (can_drain_nested(i))
				drain_client(i, UINT32_MAX, 1);
			else
				hub.counters.barriers_refused++;
		}
		client_send_ctl(idx, UCAN_MSG_ACK, 0);
		break;
	}
	case UCAN_MSG_STATS:
		handle_stats(idx);
		break;
	case UCAN_MSG_GETOPT:
		handle_getopt(idx, msg);
		break;
	case UCAN_MSG_RESET_STATS:
		for (unsigned i = 0; i < hub.nifs; i++)
			memset(&hub.ifaces[i].stats, 0, sizeof(hub.ifaces[i].stats));
		for (uint32_t i = 0; i < hub.nclients_alloc; i++) {
			struct client *cl = &hub.clients[i];
			cl->tx_frames = cl->rx_frames = cl->rx_bytes = cl->rx_drops = 0;
		}
		client_send_ctl(idx, UCAN_MSG_ACK, 0);
		break;
	}
	return 1;
}

/* A BARRIER (read at depth 0) drains the client it names (depth 1) from
 * inside the outer drain: each depth reads into buffers of its own, so the
 * outer loop's unhandled messages survive. A BARRIER read at depth 1 (only
 * a hostile client sends one on its data connection) is answered without
 * draining, counted. */
#define DRAIN_DEPTH 2
static unsigned drain_depth;

static void drain_batch(uint32_t idx, unsigned budget, int even_if_paused, uint8_t (*bufs)[UCAN_MSG_MAX])
{
	struct mmsghdr msgs[RECV_BATCH];
	struct iovec iovs[RECV_BATCH];
	uint64_t done = 0; /* frames, or 1 for any other message: a batch counts as what it holds */
	unsigned resets = 0, reads = 0;
	while (done < budget) {
		struct client *c = &hub.clients[idx];
		if (c->fd < 0 || (c->paused && !even_if_paused))
			return;
		/* as many messages as the budget's frames need if each holds as many
		 * as the fullest of the last read (a sender of batches is read a batch
		 * at a time), and few in a wakeup's first read, which has no such
		 * measure of what is queued now: a sender that switches from single
		 * frames to batches overruns its budget by FIRST_READ batches at most */
		uint64_t per_msg = c->frames_per_msg ? c->frames_per_msg : 1;
		uint64_t fit = (budget - done + per_msg - 1) / per_msg;
		unsigned cap = reads++ ? RECV_BATCH : FIRST_READ;
		unsigned want = fit < cap ? (unsigned)fit : cap;
		for (unsigned i = 0; i < want; i++) {
			iovs[i] = (struct iovec){ .iov_base = bufs[i], .iov_len = UCAN_MSG_MAX };
			msgs[i] = (struct mmsghdr){ .msg_hdr = { .msg_iov = &iovs[i], .msg_iovlen = 1 } };
		}
		int n = recvmmsg(c->fd, msgs, want, MSG_DONTWAIT, NULL);
		if (n < 0 && errno == ECONNRESET && resets++ == 0) {
			client_reader_gone(idx); /* its frames are still there: read them */
			continue;
		}
		if (n < 0) {
			if (errno != EAGAIN && errno != EINTR)
				client_close(idx, NULL);
			return;
		}
		if (n == 0) {
			client_close(idx, NULL);
			return;
		}
		/* messages already read are handled even if a frame pauses the sender */
		unsigned fullest = 1;
		for (int i = 0; i < n && hub.clients[idx].fd >= 0; i++) {
			if (msgs[i].msg_len == 0) { /* peer closed after its last message */
				client_close(idx, NULL);
				return;
			}
			if (msgs[i].msg_hdr.msg_flags & MSG_TRUNC) {
				hub.counters.proto_errors++;
				client_close(idx, "message too long");
				return;
			}
			unsigned frames = handle_message(idx, bufs[i], msgs[i].msg_len);
			done += frames;
			fullest = frames > fullest ? frames : fullest;
		}
		if (hub.clients[idx].fd >= 0)
			hub.clients[idx].frames_per_msg = fullest;
		if ((unsigned)n < want)
			return; /* drained */
	}
}

/* even_if_paused: a sender that hung up cannot be slowed down any more; read
 * what it wrote before it went, rather than losing it. */
static void drain_client(uint32_t idx, unsigned budget, int even_if_paused)
{
	static uint8_t bufs[DRAIN_DEPTH][RECV_BATCH][UCAN_MSG_MAX];
	assert(drain_depth < DRAIN_DEPTH);
	uint32_t generation = hub.clients[idx].generation;
	hub.clients[idx].draining = 1;
	drain_batch(idx, budget, even_if_paused, bufs[drain_depth++]);
	drain_depth--;
	if (hub.clients[idx].generation == generation)
		hub.clients[idx].draining = 0;
}

static int can_drain_nested(uint32_t idx)
{
	return drain_depth < DRAIN_DEPTH && !hub.clients[idx].draining;
}

/* ---- startup ---- */

static int make_dir(const char *dir)
{
	if (mkdir(dir, 0770) < 0 && errno != EEXIST) {
		hub_log("cannot create %s: %s", dir, strerror(errno));
		return -1;
	}
	return 0;
}

static int listen_socket(void)
{
	char lock_path[sizeof(hub.sock_path)];
	struct sockaddr_un addr = { .sun_family = AF_UNIX };

	if (snprintf(hub.sock_path, sizeof(hub.sock_path), "%s/%s", hub.dir, UCAN_SOCK_NAME) >=
		    (int)sizeof(hub.sock_path) ||
	    snprintf(lock_path, sizeof(lock_path), "%s/%s", hub.dir, UCAN_LOCK_NAME) >= (int)sizeof(lock_path)) {
		hub_log("socket directory path too long: %s", hub.dir);
		return -1;
	}
	if (make_dir(hub.dir) < 0)
		return -1;
	/* the lock, held for the hub's lifetime, tells a live hub from a stale socket file */
	int lock_fd = hub.lock_fd = open(lock_path, O_RDWR | O_CREAT | O_CLOEXEC, 0660);
	if (lock_fd < 0) {
		hub_log("cannot open %s: %s", lock_path, strerror(errno));
		return -1;
	}
	if (flock(lock_fd, LOCK_EX | LOCK_NB) < 0) {
		hub_log("another hub is already serving %s", hub.sock_path);
		return -1;
	}
	if (unlink(hub.sock_path) == 0)
		hub_log("replaced stale socket %s", hub.sock_path);
	hub.listen_fd = socket(AF_UNIX, SOCK_SEQPACKET | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
	if (hub.listen_fd < 0) {
		hub_log("socket: %s", strerror(errno));
		return -1;
	}
	strcpy(addr.sun_path, hub.sock_path);
	/* owner and group only (0660): whoever may use the bus shares the hub's
	 * group (compose: BENCH_GID, docs/userspace-bus.md), nobody else can send */
	mode_t old = umask(0117);
	int rc = bind(hub.listen_fd, (struct sockaddr *)&addr, sizeof(addr));
	umask(old);
	if (rc < 0 || listen(hub.listen_fd, SOMAXCONN) < 0) {
		hub_log("cannot listen on %s: %s", hub.sock_path, strerror(errno));
		return -1;
	}
	return 0;
}

static void stats_tick(void)
{
	uint64_t expirations;
	if (read(hub.stats_timer_fd, &expirations, sizeof(expirations)) < 0)
		return;
	if (hub.listen_paused) {
		hub.listen_paused = 0;
		epoll_set(hub.listen_fd, EPOLLIN, TAG_LISTEN, EPOLL_CTL_MOD);
	}
	for (unsigned i = 0; i < hub.nifs; i++) {
		struct iface *ifc = &hub.ifaces[i];
		ifc->stats.bits_per_s = ifc->window_bits / (expirations ? expirations : 1);
		ifc->stats.load_permille =
			ifc->info.bitrate ? (uint32_t)(ifc->stats.bits_per_s * 1000u / ifc->info.bitrate) : 0;
		ifc->window_bits = 0;
	}
}


/* ---- lifecycle ---- */

int hub_start(const struct hub_options *opts)
{
	hub.dir = opts->dir;
	hub.default_queue = opts->default_queue ? opts->default_queue : HUB_DEFAULT_QUEUE_FRAMES;
	hub.spin_us = opts->spin_us;
	hub.verbose = opts->verbose;
	if (hub.nifs == 0 && hub_add_iface("vcan0") < 0)
		return -1;
	for (unsigned i = 0; i < hub.nifs; i++)
		hub.ifinfos[i] = hub.ifaces[i].info;
	clock_gettime(CLOCK_MONOTONIC, &hub.start);
	if (listen_socket() < 0)
		return -1;
	hub.spare_fd = open("/dev/null", O_RDONLY | O_CLOEXEC);
	hub.epoll_fd = epoll_create1(EPOLL_CLOEXEC);
	hub.stats_timer_fd = timerfd_create(CLOCK_MONOTONIC, TFD_NONBLOCK | TFD_CLOEXEC);
	struct itimerspec second = { .it_interval = { 1, 0 }, .it_value = { 1, 0 } };
	if (hub.epoll_fd < 0 || hub.stats_timer_fd < 0 ||
	    timerfd_settime(hub.stats_timer_fd, 0, &second, NULL) < 0 ||
	    epoll_set(hub.listen_fd, EPOLLIN, TAG_LISTEN, EPOLL_CTL_ADD) < 0 ||
	    epoll_set(hub.stats_timer_fd, EPOLLIN, TAG_STATS_TIMER, EPOLL_CTL_ADD) < 0) {
		hub_log("epoll/timerfd setup: %s", strerror(errno));
		return -1;
	}
	for (unsigned i = 0; i < hub.nifs; i++) {
		struct iface *ifc = &hub.ifaces[i];
		if (!ifc->info.bitrate)
			continue;
		ifc->timerfd = timerfd_create(CLOCK_MONOTONIC, TFD_NONBLOCK | TFD_CLOEXEC);
		if (ifc->timerfd < 0 || epoll_set(ifc->timerfd, EPOLLIN, TAG_IFACE_TIMER_BASE + i, EPOLL_CTL_ADD) < 0) {
			hub_log("timerfd: %s", strerror(errno));
			return -1;
		}
	}
	for (unsigned i = 0; i < hub.nifs; i++) {
		const struct ucan_ifinfo *in = &hub.ifaces[i].info;
		static const char *const stuffing[] = { "worst", "exact", "none" };
		if (in->bitrate)
			hub_log("%s index %u mtu %u bitrate %u stuffing %s", in->name, in->ifindex, in->mtu,
				in->bitrate, stuffing[in->stuffing]);
		else
			hub_log("%s index %u mtu %u unthrottled", in->name, in->ifindex, in->mtu);
	}
	hub_log("listening on %s", hub.sock_path);
	return 0;
}

int hub_run_once(int timeout_ms)
{
	struct epoll_event events[64];
	int n = epoll_wait(hub.epoll_fd, events, 64, timeout_ms);
	if (n < 0) {
		if (errno == EINTR)
			return 0;
		hub_log("epoll_wait: %s", strerror(errno));
		return -1;
	}
	for (int i = 0; i < n; i++) {
		uint64_t tag = events[i].data.u64;
		uint32_t slot = (uint32_t)tag, generation = (uint32_t)(tag >> 32);
		if (tag == TAG_LISTEN) {
			accept_clients();
		} else if (tag == TAG_STATS_TIMER) {
			stats_tick();
		} else if (tag >= TAG_IFACE_TIMER_BASE && tag < TAG_STATS_TIMER) {
			wire_timer(&hub.ifaces[tag - TAG_IFACE_TIMER_BASE]);
		} else if (slot < hub.nclients_alloc && hub.clients[slot].fd >= 0 &&
			   hub.clients[slot].generation == generation) {
			uint32_t ev = events[i].events;
			if (ev & EPOLLOUT)
				client_flush(slot);
			if (hub.clients[slot].fd >= 0 && (ev & (EPOLLIN | EPOLLHUP | EPOLLERR)))
				drain_client(slot, FRAMES_PER_WAKEUP, !!(ev & (EPOLLHUP | EPOLLERR)));
		}
	}
	flush_dirty();
	return n;
}

int hub_run(void)
{
	uint64_t last_event_ns = 0;
	while (!hub.stop) {
		/* spinning (opt-in) saves the hub's own wakeup, about half of a hop's latency */
		int spinning = hub.spin_us && now_ns() - last_event_ns < (uint64_t)hub.spin_us * 1000;
		int n = hub_run_once(spinning ? 0 : -1);
		if (n < 0)
			return -1;
		if (n > 0 && hub.spin_us)
			last_event_ns = now_ns();
	}
	hub_log("stopping (%" PRIu64 " protocol errors)", hub.counters.proto_errors);
	return 0;
}

const char *hub_socket_path(void)
{
	return hub.sock_path;
}

void hub_shutdown(void)
{
	for (uint32_t i = 0; i < hub.nclients_alloc; i++)
		client_close(i, NULL);
	free(hub.clients);
	free(hub.dirty);
	for (unsigned i = 0; i < hub.nifs; i++) {
		free(hub.ifaces[i].pending);
		if (hub.ifaces[i].timerfd >= 0)
			close(hub.ifaces[i].timerfd);
	}
	if (hub.listen_fd >= 0) {
		unlink(hub.sock_path);
		close(hub.listen_fd);
	}
	if (hub.lock_fd >= 0)
		close(hub.lock_fd);
	if (hub.spare_fd >= 0)
		close(hub.spare_fd);
	if (hub.epoll_fd >= 0)
		close(hub.epoll_fd);
	if (hub.stats_timer_fd >= 0)
		close(hub.stats_timer_fd);
	memset(&hub, 0, sizeof(hub));
	hub.listen_fd = hub.epoll_fd = hub.stats_timer_fd = hub.lock_fd = hub.spare_fd = -1;
	hub.default_queue = HUB_DEFAULT_QUEUE_FRAMES;
}

void hub_check_invariants(void)
{
	uint32_t max_limit = hub.default_queue > UCAN_MAX_RCVBUF / CANFD_MTU ? hub.default_queue
									     : UCAN_MAX_RCVBUF / CANFD_MTU;
	(void)max_limit; /* release builds (NDEBUG) check nothing */
	assert(hub.ndirty == 0 && drain_depth == 0);
	for (uint32_t i = 0; i < hub.nclients_alloc; i++) {
		const struct client *c = &hub.clients[i];
		assert(!c->dirty && !c->draining);
		if (c->fd < 0) {
			assert(c->queue == NULL && c->queue_len == 0);
			continue;
		}
		/* (a limit lowered by SETOPT leaves what is queued: drops until below) */
		assert(c->queue_len <= c->queue_cap && c->queue_cap <= max_limit + UCAN_CTL_RESERVE);
		assert(c->queue_limit <= max_limit);
	}
}
