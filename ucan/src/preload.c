/* libucan-preload.so - makes unmodified, dynamically linked SocketCAN programs
 * use the ucan-hub bus: LD_PRELOAD=libucan-preload.so candump vcan0
 *
 * socket(PF_CAN, SOCK_RAW, CAN_RAW) returns an AF_UNIX SOCK_SEQPACKET socket
 * connected to the hub. poll/select/epoll, O_NONBLOCK and SO_RCVTIMEO stay
 * native: they work on the unix socket as they would on a CAN socket. The
 * calls that see CAN addresses, options, stamps or frame layout are
 * intercepted; every call on any other fd goes straight to libc after one
 * table lookup. SO_TIMESTAMP(NS) and SIOCGSTAMP(NS) return the one stamp the
 * hub gave the frame (the kernel's own stamp of the unix message would be
 * each reader's delivery time).
 *
 * Not emulated (documented in docs/userspace-bus.md): CAN_BCM, ISO-TP, J1939,
 * netlink (ip link), SO_TIMESTAMPING, rebinding a bound socket, programs that
 * are static or issue raw syscalls. */
#define _GNU_SOURCE
#include <dirent.h>
#include <dlfcn.h>
#include <errno.h>
#include <fcntl.h>
#include <net/if.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/time.h>
#include <sys/uio.h>
#include <sys/un.h>
#include <time.h>
#include <unistd.h>
#include <linux/sockios.h>

#include "ucan_proto.h"

#ifndef SO_TIMESTAMP_NEW /* linux < 5.1 headers: only the old options exist */
#define SO_TIMESTAMP_OLD SO_TIMESTAMP
#define SO_TIMESTAMPNS_OLD SO_TIMESTAMPNS
#define SO_TIMESTAMP_NEW 63
#define SO_TIMESTAMPNS_NEW 64
#define SIOCGSTAMP_OLD SIOCGSTAMP
#define SIOCGSTAMPNS_OLD SIOCGSTAMPNS
#endif
#ifndef SIOCGSTAMP_NEW
#define SIOCGSTAMP_NEW _IOR(SOCK_IOC_TYPE, 0x06, long long[2])
#define SIOCGSTAMPNS_NEW _IOR(SOCK_IOC_TYPE, 0x07, long long[2])
#endif

#define HUB_REPLY_TIMEOUT_MS 5000
#define IFLIST_REFRESH_NS 1000000000ll /* re-ask the hub about unknown names at most once a second */
#define FD_CHUNK_BITS 10
#define FD_CHUNKS 1024 /* tracks fds below 1M */
#define QUARANTINE 64  /* freed sockets kept alive a while for threads still using them */

#define PUBLIC __attribute__((visibility("default")))

struct csock {
	atomic_int refs; /* fds sharing this socket (dup) */
	pthread_mutex_t lock;
	int connected, bound;
	char cookie[UCAN_COOKIE_MAX];
	dev_t dev; /* the unix socket's identity: tells a descriptor closed */
	ino_t ino; /* behind the library's back and reused from ours */
	struct ucan_sockopts opts;
	struct can_filter filters[UCAN_MAX_FILTERS];
	int ioctl_stamps;	    /* SIOCGSTAMP(NS) used: stamps stay on without SO_TIMESTAMP */
	struct timespec last_stamp; /* of the last frame read, for SIOCGSTAMP(NS); 0 = none yet */
	atomic_uint mmsg_last;	    /* frames the last recvmmsg returned: sizes the next one's first read */
	atomic_uint batch_bytes;    /* longest UCAN_MSG_FRAMES the socket's SO_SNDBUF takes (0: UCAN_MSG_MAX) */
};

/* ---- real libc functions ---- */

#define REAL_DECL(ret, name, ...)                                                                                      \
	static ret (*real_##name)(__VA_ARGS__);                                                                        \
	static ret (*get_##name(void))(__VA_ARGS__)                                                                    \
	{                                                                                                              \
		if (!real_##name)                                                                                      \
			real_##name = (ret(*)(__VA_ARGS__))dlsym(RTLD_NEXT, #name);                                    \
		return real_##name;                                                                                    \
	}

REAL_DECL(int, socket, int, int, int)
REAL_DECL(int, bind, int, const struct sockaddr *, socklen_t)
REAL_DECL(int, socketpair, int, int, int, int *)
REAL_DECL(int, accept, int, struct sockaddr *, socklen_t *)
REAL_DECL(int, accept4, int, struct sockaddr *, socklen_t *, int)
REAL_DECL(int, connect, int, const struct sockaddr *, socklen_t)
REAL_DECL(int, close, int)
REAL_DECL(int, close_range, unsigned, unsigned, int)
REAL_DECL(int, setsockopt, int, int, int, const void *, socklen_t)
REAL_DECL(int, getsockopt, int, int, int, void *, socklen_t *)
REAL_DECL(int, getsockname, int, struct sockaddr *, socklen_t *)
REAL_DECL(int, getpeername, int, struct sockaddr *, socklen_t *)
REAL_DECL(int, ioctl, int, unsigned long, void *)
REAL_DECL(unsigned, if_nametoindex, const char *)
REAL_DECL(char *, if_indextoname, unsigned, char *)
REAL_DECL(ssize_t, recvmsg, int, struct msghdr *, int)
REAL_DECL(ssize_t, recvfrom, int, void *, size_t, int, struct sockaddr *, socklen_t *)
REAL_DECL(ssize_t, recv, int, void *, size_t, int)
REAL_DECL(ssize_t, read, int, void *, size_t)
REAL_DECL(ssize_t, readv, int, const struct iovec *, int)
REAL_DECL(int, recvmmsg, int, struct mmsghdr *, unsigned, int, struct timespec *)
REAL_DECL(ssize_t, sendmsg, int, const struct msghdr *, int)
REAL_DECL(ssize_t, sendto, int, const void *, size_t, int, const struct sockaddr *, socklen_t)
REAL_DECL(ssize_t, send, int, const void *, size_t, int)
REAL_DECL(ssize_t, write, int, const void *, size_t)
REAL_DECL(ssize_t, writev, int, const struct iovec *, int)
REAL_DECL(int, sendmmsg, int, struct mmsghdr *, unsigned, int)
REAL_DECL(int, dup, int)
REAL_DECL(int, dup2, int, int)
REAL_DECL(int, dup3, int, int, int)
REAL_DECL(int, fcntl, int, int, void *)
REAL_DECL(int, fcntl64, int, int, void *)

/* ---- fd table ---- */

static _Atomic(struct csock *) *fd_chunks[FD_CHUNKS];
static pthread_mutex_t table_lock = PTHREAD_MUTEX_INITIALIZER;
static struct csock *quarantine[QUARANTINE];
static unsigned quarantine_next;

static struct csock *lookup(int fd)
{
	if (fd < 0 || (unsigned)fd >= (FD_CHUNKS << FD_CHUNK_BITS))
		return NULL;
	_Atomic(struct csock *) *chunk = atomic_load_explicit(
		(_Atomic(_Atomic(struct csock *) *) *)&fd_chunks[fd >> FD_CHUNK_BITS], memory_order_acquire);
	if (!chunk)
		return NULL;
	return atomic_load_explicit(&chunk[fd & ((1 << FD_CHUNK_BITS) - 1)], memory_order_acquire);
}

static void release(struct csock *cs)
{
	if (atomic_fetch_sub(&cs->refs, 1) != 1)
		return;
	/* another thread may still be inside a call on this socket: free later */
	pthread_mutex_lock(&table_lock);
	struct csock *old = quarantine[quarantine_next];
	quarantine[quarantine_next] = cs;
	quarantine_next = (quarantine_next + 1) % QUARANTINE;
	pthread_mutex_unlock(&table_lock);
	if (old) {
		pthread_mutex_destroy(&old->lock);
		free(old);
	}
}

/* Installs cs at fd (NULL to untrack) and drops whatever was there. */
static int track(int fd, struct csock *cs)
{
	if (fd < 0 || (unsigned)fd >= (FD_CHUNKS << FD_CHUNK_BITS)) {
		if (cs) {
			errno = EMFILE;
			return -1;
		}
		return 0;
	}
	pthread_mutex_lock(&table_lock);
	_Atomic(struct csock *) *chunk = (void *)fd_chunks[fd >> FD_CHUNK_BITS];
	if (!chunk) {
		if (!cs) {
			pthread_mutex_unlock(&table_lock);
			return 0;
		}
		chunk = calloc(1u << FD_CHUNK_BITS, sizeof(*chunk));
		if (!chunk) {
			pthread_mutex_unlock(&table_lock);
			errno = ENOMEM;
			return -1;
		}
		atomic_store_explicit((_Atomic(_Atomic(struct csock *) *) *)&fd_chunks[fd >> FD_CHUNK_BITS], chunk,
				      memory_order_release);
	}
	if (cs)
		atomic_fetch_add(&cs->refs, 1);
	struct csock *old = atomic_exchange(&chunk[fd & ((1 << FD_CHUNK_BITS) - 1)], cs);
	pthread_mutex_unlock(&table_lock);
	if (old)
		release(old);
	return 0;
}

/* A descriptor closed without close() (fclose(fdopen(fd)), the raw syscall)
 * and reused stays in the table: before the library acts on a descriptor in
 * a call that is not per frame, or when a per-frame call fails, it checks the
 * descriptor is still its socket, and forgets it if not. */
static int remember_identity(int fd, struct csock *cs)
{
	struct stat st;
	if (fstat(fd, &st) < 0)
		return -1;
	cs->dev = st.st_dev;
	cs->ino = st.st_ino;
	return 0;
}

static int still_ours(int fd, const struct csock *cs)
{
	struct stat st;
	int saved = errno;
	int ours = fstat(fd, &st) == 0 && S_ISSOCK(st.st_mode) && st.st_dev == cs->dev && st.st_ino == cs->ino;
	errno = saved;
	return ours;
}

static struct csock *lookup_live(int fd)
{
	struct csock *cs = lookup(fd);
	if (cs && !still_ours(fd, cs)) {
		track(fd, NULL);
		return NULL;
	}
	return cs;
}

/* After a failed per-frame call: 1 if fd was not ours any more (now forgotten). */
static int forget_if_stale(int fd, struct csock *cs)
{
	if (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR || still_ours(fd, cs))
		return 0;
	track(fd, NULL);
	return 1;
}

/* A descriptor the kernel just handed out is not a socket of ours, whatever the table says. */
static int fresh_fd(int fd)
{
	if (fd >= 0 && lookup(fd)) {
		int saved = errno;
		track(fd, NULL);
		errno = saved;
	}
	return fd;
}

/* ---- talking to the hub ---- */

static const char *hub_dir(void)
{
	const char *dir = getenv(UCAN_DIR_ENV);
	return dir && *dir ? dir : UCAN_DEFAULT_DIR;
}

static int hub_addr(struct sockaddr_un *addr)
{
	memset(addr, 0, sizeof(*addr));
	addr->sun_family = AF_UNIX;
	if (snprintf(addr->sun_path, sizeof(addr->sun_path), "%s/%s", hub_dir(), UCAN_SOCK_NAME) >=
	    (int)sizeof(addr->sun_path)) {
		errno = ENAMETOOLONG;
		return -1;
	}
	return 0;
}

static atomic_int hub_complained;

static void complain_hub_down(const char *path, int err)
{
	/* one line per outage, not one per call */
	if (atomic_exchange(&hub_complained, 1) == 0)
		fprintf(stderr, "ucan: cannot reach CAN hub at %s: %s\n", path, strerror(err));
}

/* Connects fd (blocking for the duration) to the hub. */
static int hub_connect_as(int fd, int complain)
{
	struct sockaddr_un addr;
	if (hub_addr(&addr) < 0)
		return -1;
	int flags = get_fcntl()(fd, F_GETFL, NULL);
	if (flags >= 0 && (flags & O_NONBLOCK))
		get_fcntl()(fd, F_SETFL, (void *)(intptr_t)(flags & ~O_NONBLOCK));
	int rc = get_connect()(fd, (struct sockaddr *)&addr, sizeof(addr));
	int err = errno;
	if (flags >= 0 && (flags & O_NONBLOCK))
		get_fcntl()(fd, F_SETFL, (void *)(intptr_t)flags);
	if (rc < 0) {
		if (complain)
			complain_hub_down(addr.sun_path, err);
		errno = err;
		return -1;
	}
	atomic_store(&hub_complained, 0);
	return 0;
}

static int hub_connect(int fd)
{
	return hub_connect_as(fd, 1);
}

static int wait_readable(int fd)
{
	struct pollfd pfd = { .fd = fd, .events = POLLIN };
	int rc;
	do
		rc = poll(&pfd, 1, HUB_REPLY_TIMEOUT_MS);
	while (rc < 0 && errno == EINTR);
	if (rc == 0) {
		fprintf(stderr, "ucan: CAN hub did not answer within %d ms\n", HUB_REPLY_TIMEOUT_MS);
		errno = ETIMEDOUT;
		return -1;
	}
	return rc < 0 ? -1 : 0;
}

/* One query on a connection of its own: no state shared between threads or
 * with a forked child. Returns the reply length. */
static ssize_t hub_query(const void *req, size_t req_len, void *reply, size_t reply_len)
{
	int fd = get_socket()(AF_UNIX, SOCK_SEQPACKET | SOCK_CLOEXEC, 0);
	if (fd < 0)
		return -1;
	ssize_t n = -1;
	if (hub_connect(fd) == 0 && get_send()(fd, req, req_len, MSG_NOSIGNAL) == (ssize_t)req_len &&
	    wait_readable(fd) == 0)
		n = get_recv()(fd, reply, reply_len, 0);
	int err = errno;
	get_close()(fd);
	if (n == 0)
		err = ENETDOWN;
	errno = err;
	return n > 0 ? n : -1;
}

/* ---- interface table (names, indexes, MTU), cached per process ---- */

static pthread_mutex_t iflist_lock = PTHREAD_MUTEX_INITIALIZER;
static struct ucan_iflist iflist;
static int64_t iflist_fetched_ns;

static int64_t now_ns(void)
{
	struct timespec ts;
	clock_gettime(CLOCK_MONOTONIC, &ts);
	return (int64_t)ts.tv_sec * 1000000000ll + ts.tv_nsec;
}

static int cached_iface(const char *name, uint32_t ifindex, struct ucan_ifinfo *out, int64_t *fetched_ns)
{
	int found = -1;
	pthread_mutex_lock(&iflist_lock);
	for (uint32_t i = 0; i < iflist.count && i < UCAN_MAX_IFACES && found < 0; i++) {
		const struct ucan_ifinfo *ifi = &iflist.ifs[i];
		if (name ? strncmp(ifi->name, name, sizeof(ifi->name)) == 0 : ifi->ifindex == ifindex) {
			*out = *ifi;
			found = 0;
		}
	}
	*fetched_ns = iflist_fetched_ns;
	pthread_mutex_unlock(&iflist_lock);
	return found;
}

/* Looks up by name (if name) or index; refreshes the cache on a miss. The
 * hub is asked without holding the lock: a query can take seconds (a stopped
 * hub), and neither other threads nor a child forked meanwhile may wait on it. */
static int find_iface(const char *name, uint32_t ifindex, struct ucan_ifinfo *out)
{
	int64_t fetched;
	if (cached_iface(name, ifindex, out, &fetched) == 0)
		return 0;
	int64_t now = now_ns();
	if (fetched && now - fetched < IFLIST_REFRESH_NS)
		return -1;
	uint32_t type = UCAN_MSG_IFLIST;
	struct ucan_iflist fresh;
	int saved = errno;
	ssize_t n = hub_query(&type, sizeof(type), &fresh, sizeof(fresh));
	errno = saved;
	pthread_mutex_lock(&iflist_lock);
	iflist_fetched_ns = now;
	if (n == (ssize_t)sizeof(fresh) && fresh.type == UCAN_MSG_IFLIST)
		iflist = fresh;
	pthread_mutex_unlock(&iflist_lock);
	return cached_iface(name, ifindex, out, &fetched);
}

/* ---- socket settings ---- */

static size_t opts_size(const struct csock *cs)
{
	return sizeof(cs->opts) + cs->opts.nfilters * sizeof(struct can_filter);
}

/* Sends the full settings; with a barrier, returns only once the hub applies them. */
static int push_opts(struct csock *cs, int fd, uint32_t type, int barrier)
{
	uint8_t msg[sizeof(struct ucan_sockopts) + sizeof(cs->filters)];
	cs->opts.type = type;
	memcpy(msg, &cs->opts, sizeof(cs->opts));
	memcpy(msg + sizeof(cs->opts), cs->filters, cs->opts.nfilters * sizeof(struct can_filter));
	if (get_send()(fd, msg, opts_size(cs), MSG_NOSIGNAL) != (ssize_t)opts_size(cs)) {
		errno = ENETDOWN;
		return -1;
	}
	if (!barrier)
		return 0;
	struct ucan_barrier req = { .type = UCAN_MSG_BARRIER };
	struct ucan_ctl ack;
	memcpy(req.cookie, cs->cookie, sizeof(req.cookie));
	if (hub_query(&req, sizeof(req), &ack, sizeof(ack)) != (ssize_t)sizeof(ack)) {
		errno = ENETDOWN;
		return -1;
	}
	return 0;
}

static void default_opts(struct csock *cs)
{
	memset(&cs->opts, 0, sizeof(cs->opts));
	cs->opts.loopback = 1;
	cs->opts.nfilters = 1; /* kernel default: one filter {0, 0} receives everything */
	memset(cs->filters, 0, sizeof(cs->filters[0]));
}

/* Abstract-namespace name that identifies this socket to the hub and survives exec. */
static int bind_cookie(int fd, struct csock *cs)
{
	static atomic_uint counter;
	struct sockaddr_un addr = { .sun_family = AF_UNIX };
	unsigned rnd = 0;
	struct timespec ts;
	clock_gettime(CLOCK_REALTIME, &ts);
	rnd = (unsigned)ts.tv_nsec ^ (unsigned)((uintptr_t)cs >> 4);
	int n = snprintf(cs->cookie, sizeof(cs->cookie), "%s%d/%u/%08x", UCAN_COOKIE_PREFIX, (int)getpid(),
			 atomic_fetch_add(&counter, 1), rnd);
	memcpy(addr.sun_path + 1, cs->cookie, (size_t)n);
	return get_bind()(fd, (struct sockaddr *)&addr, (socklen_t)(offsetof(struct sockaddr_un, sun_path) + 1 + n));
}

static int ensure_connected(struct csock *cs, int fd)
{
	if (cs->connected)
		return 0;
	if (hub_connect(fd) < 0) {
		errno = ENETDOWN;
		return -1;
	}
	cs->connected = 1;
	return 0;
}

/* ---- socket(), bind(), close() and friends ---- */

PUBLIC int socket(int domain, int type, int protocol)
{
	if (domain != PF_CAN)
		return fresh_fd(get_socket()(domain, type, protocol));
	int base = type & ~(SOCK_NONBLOCK | SOCK_CLOEXEC);
	if (base != SOCK_RAW || protocol != CAN_RAW) {
		static atomic_int told;
		if (atomic_exchange(&told, 1) == 0)
			fprintf(stderr, "ucan: only CAN_RAW sockets are emulated (type %d protocol %d refused)\n", base,
				protocol);
		errno = EPROTONOSUPPORT;
		return -1;
	}
	struct csock *cs = calloc(1, sizeof(*cs));
	if (!cs) {
		errno = ENOMEM;
		return -1;
	}
	pthread_mutex_init(&cs->lock, NULL);
	default_opts(cs);
	int fd = get_socket()(AF_UNIX, SOCK_SEQPACKET | (type & (SOCK_NONBLOCK | SOCK_CLOEXEC)), 0);
	if (fd < 0 || bind_cookie(fd, cs) < 0 || remember_identity(fd, cs) < 0 || track(fd, cs) < 0) {
		int err = errno;
		if (fd >= 0)
			get_close()(fd);
		pthread_mutex_destroy(&cs->lock);
		free(cs);
		errno = err;
		return -1;
	}
	/* connected from the start, an unbound socket polls and reads like the
	 * kernel's: nothing to read, writable (an unconnected one would report
	 * POLLHUP). The hub sends nothing before BIND. Hub down: bind() retries. */
	cs->connected = hub_connect_as(fd, 0) == 0;
	return fd;
}

PUBLIC int socketpair(int domain, int type, int protocol, int sv[2])
{
	int rc = get_socketpair()(domain, type, protocol, sv);
	if (rc == 0) {
		fresh_fd(sv[0]);
		fresh_fd(sv[1]);
	}
	return rc;
}

PUBLIC int accept(int fd, struct sockaddr *addr, socklen_t *len)
{
	return fresh_fd(get_accept()(fd, addr, len));
}

PUBLIC int accept4(int fd, struct sockaddr *addr, socklen_t *len, int flags)
{
	return fresh_fd(get_accept4()(fd, addr, len, flags));
}

PUBLIC int bind(int fd, const struct sockaddr *addr, socklen_t len)
{
	struct csock *cs = lookup_live(fd);
	if (!cs)
		return get_bind()(fd, addr, len);
	const struct sockaddr_can *can = (const struct sockaddr_can *)addr;
	if (!addr || len < offsetof(struct sockaddr_can, can_addr) || can->can_family != AF_CAN) {
		errno = EINVAL;
		return -1;
	}
	struct ucan_ifinfo ifi;
	if (can->can_ifindex != 0 && find_iface(NULL, (uint32_t)can->can_ifindex, &ifi) < 0) {
		errno = ENODEV;
		return -1;
	}
	pthread_mutex_lock(&cs->lock);
	int rc = -1;
	if (cs->bound) {
		if (cs->opts.ifindex == (uint32_t)can->can_ifindex)
			rc = 0;
		else {
			fprintf(stderr, "ucan: rebinding a bound CAN socket is not emulated\n");
			errno = EINVAL;
		}
		goto out;
	}
	if (ensure_connected(cs, fd) < 0)
		goto out;
	cs->opts.ifindex = (uint32_t)can->can_ifindex;
	if (push_opts(cs, fd, UCAN_MSG_BIND, 0) < 0)
		goto out;
	/* the ACK is the first message the hub sends on this connection */
	struct ucan_ctl ack;
	if (wait_readable(fd) < 0)
		goto out;
	ssize_t n = get_recv()(fd, &ack, sizeof(ack), MSG_DONTWAIT);
	if (n != (ssize_t)sizeof(ack) || ack.type != UCAN_MSG_ACK) {
		errno = ENETDOWN;
		goto out;
	}
	if (ack.status) {
		errno = ack.status;
		goto out;
	}
	cs->bound = 1;
	rc = 0;
out:
	pthread_mutex_unlock(&cs->lock);
	return rc;
}

PUBLIC int close(int fd)
{
	if (lookup(fd))
		track(fd, NULL);
	return get_close()(fd);
}

PUBLIC int close_range(unsigned first, unsigned last, int flags)
{
	if (!(flags & CLOSE_RANGE_CLOEXEC))
		for (unsigned fd = first; fd <= last && fd < (FD_CHUNKS << FD_CHUNK_BITS); fd++)
			if (lookup((int)fd))
				track((int)fd, NULL);
	return get_close_range()(first, last, flags);
}

static int track_dup(int oldfd, int newfd)
{
	struct csock *cs = lookup_live(oldfd);
	if (newfd >= 0 && oldfd != newfd)
		track(newfd, cs); /* also forgets whatever newfd was before */
	return newfd;
}

PUBLIC int dup(int fd)
{
	return track_dup(fd, get_dup()(fd));
}

PUBLIC int dup2(int fd, int newfd)
{
	return track_dup(fd, get_dup2()(fd, newfd));
}

PUBLIC int dup3(int fd, int newfd, int flags)
{
	return track_dup(fd, get_dup3()(fd, newfd, flags));
}

static int fcntl_common(int (*real)(int, int, void *), int fd, int cmd, void *arg)
{
	int rc = real(fd, cmd, arg);
	if ((cmd == F_DUPFD || cmd == F_DUPFD_CLOEXEC) && rc >= 0)
		track_dup(fd, rc);
	return rc;
}

PUBLIC int fcntl(int fd, int cmd, ...)
{
	va_list ap;
	va_start(ap, cmd);
	void *arg = va_arg(ap, void *);
	va_end(ap);
	return fcntl_common(get_fcntl(), fd, cmd, arg);
}

PUBLIC int fcntl64(int fd, int cmd, ...)
{
	va_list ap;
	va_start(ap, cmd);
	void *arg = va_arg(ap, void *);
	va_end(ap);
	return fcntl_common(get_fcntl64() ? get_fcntl64() : get_fcntl(), fd, cmd, arg);
}

/* ---- options ---- */

static int int_opt(const void *val, socklen_t len, uint8_t *out)
{
	if (!val || len != sizeof(int)) {
		errno = EINVAL;
		return -1;
	}
	int v;
	memcpy(&v, val, sizeof(v));
	*out = v ? 1 : 0;
	return 0;
}

/* ---- timestamps: the hub's one stamp per frame ---- */

static uint8_t ts_kind(int name)
{
	switch (name) {
	case SO_TIMESTAMP_OLD: return UCAN_TS_USEC;
	case SO_TIMESTAMPNS_OLD: return UCAN_TS_NSEC;
	case SO_TIMESTAMP_NEW: return UCAN_TS_USEC_NEW;
	case SO_TIMESTAMPNS_NEW: return UCAN_TS_NSEC_NEW;
	default: return UCAN_TS_NONE;
	}
}

/* As the kernel's sock_set_timestamp: one kind at a time, 0 turns both off. */
static int set_timestamps(struct csock *cs, int fd, int name, const void *val, socklen_t len)
{
	int on;
	if (!val || len < (socklen_t)sizeof(int)) {
		errno = EINVAL;
		return -1;
	}
	memcpy(&on, val, sizeof(on));
	pthread_mutex_lock(&cs->lock);
	uint8_t before = cs->opts.timestamps;
	cs->opts.timestamps = on ? ts_kind(name) : cs->ioctl_stamps ? UCAN_TS_IOCTL : UCAN_TS_NONE;
	int rc = 0;
	/* synchronous like the other options: frames after this call carry stamps */
	if (cs->bound && cs->opts.timestamps != before)
		rc = push_opts(cs, fd, UCAN_MSG_SETOPT, 1);
	pthread_mutex_unlock(&cs->lock);
	return rc;
}

/* SIOCGSTAMP(NS): the stamp of the last frame read without SO_TIMESTAMP(NS).
 * The first call turns stamps on and, with nothing read yet, fails with
 * ENOENT, as the kernel's. */
static int get_stamp_ioctl(struct csock *cs, int fd, unsigned long request, void *arg)
{
	if (!arg) {
		errno = EFAULT;
		return -1;
	}
	pthread_mutex_lock(&cs->lock);
	struct timespec ts = cs->last_stamp;
	int rc = 0;
	if (!cs->ioctl_stamps) {
		cs->ioctl_stamps = 1;
		if (cs->opts.timestamps == UCAN_TS_NONE) {
			cs->opts.timestamps = UCAN_TS_IOCTL;
			if (cs->bound)
				rc = push_opts(cs, fd, UCAN_MSG_SETOPT, 1);
		}
	}
	pthread_mutex_unlock(&cs->lock);
	if (rc < 0)
		return -1;
	if (ts.tv_sec == 0 && ts.tv_nsec == 0) {
		errno = ENOENT;
		return -1;
	}
	int64_t pair[2] = { ts.tv_sec, request == SIOCGSTAMP_OLD || request == SIOCGSTAMP_NEW ? ts.tv_nsec / 1000
											       : ts.tv_nsec };
	if (request == SIOCGSTAMP_OLD) {
		struct timeval tv = { .tv_sec = ts.tv_sec, .tv_usec = ts.tv_nsec / 1000 };
		memcpy(arg, &tv, sizeof(tv));
	} else if (request == SIOCGSTAMPNS_OLD) {
		memcpy(arg, &ts, sizeof(ts));
	} else {
		memcpy(arg, pair, sizeof(pair));
	}
	return 0;
}

/* Appends the stamp's control message after whatever the kernel put there
 * (used bytes of room); MSG_CTRUNC if it does not fit, as put_cmsg does. */
static void put_stamp_cmsg(struct msghdr *user, size_t used, size_t room, uint8_t kind, const struct timespec *ts)
{
	int64_t data[2] = { ts->tv_sec, kind == UCAN_TS_USEC || kind == UCAN_TS_USEC_NEW ? ts->tv_nsec / 1000 : ts->tv_nsec };
	static const int types[] = { [UCAN_TS_USEC] = SO_TIMESTAMP_OLD, [UCAN_TS_NSEC] = SO_TIMESTAMPNS_OLD,
				     [UCAN_TS_USEC_NEW] = SO_TIMESTAMP_NEW, [UCAN_TS_NSEC_NEW] = SO_TIMESTAMPNS_NEW };
	static_assert(sizeof(struct timeval) == sizeof(data) && sizeof(struct timespec) == sizeof(data),
		      "old and new stamp layouts agree on this ABI");
	size_t off = CMSG_ALIGN(used);
	if (!user->msg_control || off + CMSG_LEN(sizeof(data)) > room) {
		user->msg_flags |= MSG_CTRUNC;
		user->msg_controllen = used;
		return;
	}
	struct cmsghdr *cm = (struct cmsghdr *)((uint8_t *)user->msg_control + off);
	cm->cmsg_level = SOL_SOCKET;
	cm->cmsg_type = types[kind];
	cm->cmsg_len = CMSG_LEN(sizeof(data));
	memcpy(CMSG_DATA(cm), data, sizeof(data));
	size_t end = off + CMSG_SPACE(sizeof(data));
	user->msg_controllen = end < room ? end : room;
}

PUBLIC int setsockopt(int fd, int level, int name, const void *val, socklen_t len)
{
	struct csock *cs = lookup_live(fd);
	if (!cs)
		return get_setsockopt()(fd, level, name, val, len);
	if (level == SOL_SOCKET && ts_kind(name) != UCAN_TS_NONE)
		return set_timestamps(cs, fd, name, val, len);
	if (level == SOL_SOCKET) {
		int rc = get_setsockopt()(fd, level, name, val, len);
		if (rc == 0 && (name == SO_SNDBUF || name == SO_SNDBUFFORCE))
			atomic_store(&cs->batch_bytes, 0); /* found again by the next sendmmsg */
		if (rc == 0 && (name == SO_RCVBUF || name == SO_RCVBUFFORCE) && len == sizeof(int)) {
			int bytes;
			memcpy(&bytes, val, sizeof(bytes));
			pthread_mutex_lock(&cs->lock);
			cs->opts.rcvbuf = bytes > 0 ? (uint32_t)bytes : 0;
			if (cs->bound)
				rc = push_opts(cs, fd, UCAN_MSG_SETOPT, 0);
			pthread_mutex_unlock(&cs->lock);
		}
		return rc;
	}
	if (level != SOL_CAN_RAW) {
		errno = ENOPROTOOPT;
		return -1;
	}
	pthread_mutex_lock(&cs->lock);
	int rc = 0;
	switch (name) {
	case CAN_RAW_FILTER:
		if (len % sizeof(struct can_filter) != 0 || len > sizeof(cs->filters) || (len && !val)) {
			errno = EINVAL;
			rc = -1;
			break;
		}
		if (len)
			memcpy(cs->filters, val, len);
		cs->opts.nfilters = len / sizeof(struct can_filter);
		break;
	case CAN_RAW_ERR_FILTER:
		if (!val || len != sizeof(can_err_mask_t)) {
			errno = EINVAL;
			rc = -1;
			break;
		}
		memcpy(&cs->opts.err_mask, val, sizeof(cs->opts.err_mask));
		cs->opts.err_mask &= CAN_ERR_MASK;
		break;
	case CAN_RAW_LOOPBACK:
		rc = int_opt(val, len, &cs->opts.loopback);
		break;
	case CAN_RAW_RECV_OWN_MSGS:
		rc = int_opt(val, len, &cs->opts.recv_own);
		break;
	case CAN_RAW_FD_FRAMES:
		rc = int_opt(val, len, &cs->opts.fd_frames);
		break;
	case CAN_RAW_JOIN_FILTERS:
		rc = int_opt(val, len, &cs->opts.join_filters);
		break;
	default:
		errno = ENOPROTOOPT;
		rc = -1;
	}
	/* the kernel applies options at once: so must the hub, before we return */
	if (rc == 0 && cs->bound)
		rc = push_opts(cs, fd, UCAN_MSG_SETOPT, 1);
	pthread_mutex_unlock(&cs->lock);
	return rc;
}

static int put_int_opt(void *val, socklen_t *len, int v)
{
	if (!val || !len || *len < (socklen_t)sizeof(int)) {
		errno = EINVAL;
		return -1;
	}
	memcpy(val, &v, sizeof(v));
	*len = sizeof(int);
	return 0;
}

PUBLIC int getsockopt(int fd, int level, int name, void *val, socklen_t *len)
{
	struct csock *cs = lookup_live(fd);
	if (!cs)
		return get_getsockopt()(fd, level, name, val, len);
	if (level == SOL_SOCKET) {
		switch (name) {
		case SO_DOMAIN:
			return put_int_opt(val, len, PF_CAN);
		case SO_TYPE:
			return put_int_opt(val, len, SOCK_RAW);
		case SO_PROTOCOL:
			return put_int_opt(val, len, CAN_RAW);
		case SO_TIMESTAMP_OLD:
		case SO_TIMESTAMPNS_OLD:
		case SO_TIMESTAMP_NEW:
		case SO_TIMESTAMPNS_NEW:
			return put_int_opt(val, len, cs->opts.timestamps == ts_kind(name));
		default:
			return get_getsockopt()(fd, level, name, val, len);
		}
	}
	if (level != SOL_CAN_RAW) {
		errno = EOPNOTSUPP;
		return -1;
	}
	pthread_mutex_lock(&cs->lock);
	int rc;
	switch (name) {
	case CAN_RAW_FILTER: {
		socklen_t need = (socklen_t)(cs->opts.nfilters * sizeof(struct can_filter));
		if (!len) {
			errno = EFAULT;
			rc = -1;
		} else if (*len < need) {
			*len = need; /* like the kernel: ERANGE and the size needed */
			errno = ERANGE;
			rc = -1;
		} else {
			memcpy(val, cs->filters, need);
			*len = need;
			rc = 0;
		}
		break;
	}
	case CAN_RAW_ERR_FILTER:
		if (!len || *len < (socklen_t)sizeof(can_err_mask_t)) {
			errno = EINVAL;
			rc = -1;
		} else {
			memcpy(val, &cs->opts.err_mask, sizeof(can_err_mask_t));
			*len = sizeof(can_err_mask_t);
			rc = 0;
		}
		break;
	case CAN_RAW_LOOPBACK:
		rc = put_int_opt(val, len, cs->opts.loopback);
		break;
	case CAN_RAW_RECV_OWN_MSGS:
		rc = put_int_opt(val, len, cs->opts.recv_own);
		break;
	case CAN_RAW_FD_FRAMES:
		rc = put_int_opt(val, len, cs->opts.fd_frames);
		break;
	case CAN_RAW_JOIN_FILTERS:
		rc = put_int_opt(val, len, cs->opts.join_filters);
		break;
	default:
		errno = ENOPROTOOPT;
		rc = -1;
	}
	pthread_mutex_unlock(&cs->lock);
	return rc;
}

static void fill_can_addr(struct sockaddr *addr, socklen_t *len, uint32_t ifindex)
{
	struct sockaddr_can can;
	memset(&can, 0, sizeof(can));
	can.can_family = AF_CAN;
	can.can_ifindex = (int)ifindex;
	socklen_t full = offsetof(struct sockaddr_can, can_addr); /* the kernel's RAW_MIN_NAMELEN */
	if (addr && len)
		memcpy(addr, &can, *len < full ? *len : full);
	if (len)
		*len = full;
}

PUBLIC int getsockname(int fd, struct sockaddr *addr, socklen_t *len)
{
	struct csock *cs = lookup_live(fd);
	if (!cs)
		return get_getsockname()(fd, addr, len);
	fill_can_addr(addr, len, cs->opts.ifindex);
	return 0;
}

PUBLIC int getpeername(int fd, struct sockaddr *addr, socklen_t *len)
{
	if (!lookup_live(fd))
		return get_getpeername()(fd, addr, len);
	errno = EOPNOTSUPP;
	return -1;
}

/* ---- interface queries ---- */

PUBLIC int ioctl(int fd, unsigned long request, ...)
{
	va_list ap;
	va_start(ap, request);
	void *arg = va_arg(ap, void *);
	va_end(ap);

	struct ifreq *ifr = arg;
	struct ucan_ifinfo ifi;
	struct csock *cs = lookup_live(fd);
	int is_can = cs != NULL;
	switch (request) {
	case SIOCGSTAMP_OLD:
	case SIOCGSTAMPNS_OLD:
	case SIOCGSTAMP_NEW:
	case SIOCGSTAMPNS_NEW:
		if (cs)
			return get_stamp_ioctl(cs, fd, request, arg);
		return get_ioctl()(fd, request, arg);
	case SIOCGIFINDEX:
	case SIOCGIFMTU:
	case SIOCGIFFLAGS:
		if (ifr && find_iface(ifr->ifr_name, 0, &ifi) == 0) {
			if (request == SIOCGIFINDEX)
				ifr->ifr_ifindex = (int)ifi.ifindex;
			else if (request == SIOCGIFMTU)
				ifr->ifr_mtu = (int)ifi.mtu;
			else
				ifr->ifr_flags = IFF_UP | IFF_RUNNING | IFF_NOARP;
			return 0;
		}
		break;
	case SIOCGIFNAME:
		if (ifr && find_iface(NULL, (uint32_t)ifr->ifr_ifindex, &ifi) == 0) {
			memcpy(ifr->ifr_name, ifi.name, IFNAMSIZ);
			return 0;
		}
		break;
	default:
		return get_ioctl()(fd, request, arg);
	}
	if (is_can) {
		errno = ENODEV; /* no such CAN interface (the hub may be down) */
		return -1;
	}
	return get_ioctl()(fd, request, arg);
}

PUBLIC unsigned if_nametoindex(const char *name)
{
	struct ucan_ifinfo ifi;
	if (name && find_iface(name, 0, &ifi) == 0)
		return ifi.ifindex;
	return get_if_nametoindex()(name);
}

PUBLIC char *if_indextoname(unsigned ifindex, char name[IF_NAMESIZE])
{
	struct ucan_ifinfo ifi;
	if (name && find_iface(NULL, ifindex, &ifi) == 0) {
		memcpy(name, ifi.name, IFNAMSIZ);
		return name;
	}
	return get_if_indextoname()(ifindex, name);
}

/* ---- receiving ---- */

static size_t iov_total(const struct iovec *iov, size_t n)
{
	size_t total = 0;
	for (size_t i = 0; i < n; i++)
		total += iov[i].iov_len;
	return total;
}

static void iov_gather(const struct iovec *iov, size_t n, void *out, size_t len)
{
	for (size_t i = 0; i < n && len; i++) {
		size_t k = iov[i].iov_len < len ? iov[i].iov_len : len;
		memcpy(out, iov[i].iov_base, k);
		out = (uint8_t *)out + k;
		len -= k;
	}
}

static void iov_scatter(const struct iovec *iov, size_t n, const void *in, size_t len)
{
	for (size_t i = 0; i < n && len; i++) {
		size_t k = iov[i].iov_len < len ? iov[i].iov_len : len;
		memcpy(iov[i].iov_base, in, k);
		in = (const uint8_t *)in + k;
		len -= k;
	}
}

/* An unbound socket that could not reach the hub: nothing ever arrives, but
 * O_NONBLOCK, MSG_DONTWAIT and SO_RCVTIMEO (set natively) apply as usual. */
static int recv_nothing(int fd, int flags)
{
	int fl = get_fcntl()(fd, F_GETFL, NULL);
	if ((flags & MSG_DONTWAIT) || (fl >= 0 && (fl & O_NONBLOCK))) {
		errno = EAGAIN;
		return -1;
	}
	struct timeval tv = { 0, 0 };
	socklen_t len = sizeof(tv);
	get_getsockopt()(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, &len);
	struct timespec ts = { tv.tv_sec, tv.tv_usec * 1000 };
	int forever = tv.tv_sec == 0 && tv.tv_usec == 0;
	if (ppoll(NULL, 0, forever ? NULL : &ts, NULL) < 0)
		return -1; /* EINTR */
	errno = EAGAIN;
	return -1;
}

/* Hub messages are told apart by length alone (ucan_proto.h): 16 / 72 bytes a bare frame,
 * 40 / 96 a frame behind its ucan_rxhdr, 8 a control reply. The hub switches a socket to
 * headers when it needs them, without a notice on the socket: a socket inherited across exec
 * may still hold bare frames queued before the switch, and several threads may read it. Each
 * message is decoded by its length. */
static int bare_frame_len(size_t len)
{
	return len == CAN_MTU || len == CANFD_MTU;
}

/* What a received frame tells the program besides its bytes, for recvmsg and
 * recvmmsg alike: flags (MSG_DONTROUTE, MSG_CONFIRM for its own), the stamp as
 * a control message after the used bytes of controllen (or kept for
 * SIOCGSTAMP), the source interface as msg_name. hdr NULL: a bare frame. */
static void frame_meta(struct csock *cs, struct msghdr *user, const struct ucan_rxhdr *hdr, size_t used,
		       size_t controllen, int native_flags)
{
	uint32_t ifindex = cs->opts.ifindex;
	int own = 0;
	struct timespec stamp = { 0, 0 };
	if (hdr) {
		ifindex = hdr->ifindex;
		own = hdr->flags & UCAN_RX_OWN;
		stamp = (struct timespec){ (time_t)hdr->stamp_sec, (long)hdr->stamp_nsec };
	}
	uint8_t ts = cs->opts.timestamps;
	if (ts != UCAN_TS_NONE && stamp.tv_sec == 0) /* queued before stamps were asked for */
		clock_gettime(CLOCK_REALTIME, &stamp);
	if (stamp.tv_sec && ts < UCAN_TS_USEC) /* as linux 6.1: a stamp sent as a control */
		cs->last_stamp = stamp;		 /* message is not SIOCGSTAMP's any more */
	user->msg_controllen = used;
	user->msg_flags = native_flags | MSG_DONTROUTE | (own ? MSG_CONFIRM : 0);
	if (ts >= UCAN_TS_USEC)
		put_stamp_cmsg(user, used, controllen, ts, &stamp);
	if (user->msg_name)
		fill_can_addr(user->msg_name, &user->msg_namelen, ifindex);
	else
		user->msg_namelen = 0;
}

static ssize_t can_recvmsg(struct csock *cs, int fd, struct msghdr *user, int flags)
{
	if (!cs->bound && !cs->connected)
		return recv_nothing(fd, flags);
	struct iovec iov[UIO_MAXIOV];
	if (user->msg_iovlen + 1 > UIO_MAXIOV) {
		errno = EMSGSIZE;
		return -1;
	}
	size_t controllen = user->msg_controllen;
	for (;;) {
		/* Every message is read behind a header-sized buffer and decoded by its length
		 * (bare_frame_len), whatever the socket's mode: a thread that reads while another
		 * takes the switch to headers, or bare frames queued before it, come out whole. */
		struct ucan_rxhdr hdr;
		struct msghdr msg = {
			.msg_iov = iov,
			.msg_iovlen = user->msg_iovlen + 1,
			.msg_control = user->msg_control,
			.msg_controllen = controllen,
		};
		iov[0].iov_base = &hdr;
		iov[0].iov_len = sizeof(hdr);
		memcpy(&iov[1], user->msg_iov, user->msg_iovlen * sizeof(struct iovec));

		/* MSG_TRUNC: the message's own length, so a frame cut to 8 bytes by a small
		 * buffer is not taken for a control reply (which is 8 bytes long) */
		ssize_t n = get_recvmsg()(fd, &msg, flags | MSG_TRUNC);
		if (n < 0) {
			if (errno == ECONNRESET || errno == EPIPE || errno == ENOTCONN)
				errno = ENETDOWN;
			return -1;
		}
		if (n == 0) { /* hub went away: like an interface going down */
			errno = ENETDOWN;
			return -1;
		}
		if (n == (ssize_t)sizeof(struct ucan_ctl)) {
			/* a control reply: after BIND's ACK (read by bind) the hub sends none on a data
			 * socket, so a second reader cannot take it between this peek and its consume */
			if (flags & MSG_PEEK) { /* consume it so the peeked frame is the next one */
				struct ucan_ctl ctl;
				get_recv()(fd, &ctl, sizeof(ctl), MSG_DONTWAIT);
			}
			continue;
		}
		size_t room = iov_total(user->msg_iov, user->msg_iovlen);
		int native_flags = msg.msg_flags;
		int headed = !bare_frame_len((size_t)n);
		if (headed && (size_t)n < sizeof(hdr))
			continue; /* not a message the hub sends */
		if (!headed) {
			/* its first bytes went to hdr, the rest to the program's buffer: put them together there */
			uint8_t frame[CANFD_MTU];
			size_t head = (size_t)n < sizeof(hdr) ? (size_t)n : sizeof(hdr);
			size_t want = (size_t)n < room ? (size_t)n : room;
			memcpy(frame, &hdr, head);
			if (want > head)
				iov_gather(user->msg_iov, user->msg_iovlen, frame + head, want - head);
			iov_scatter(user->msg_iov, user->msg_iovlen, frame, want);
			native_flags = (native_flags & ~MSG_TRUNC) | ((size_t)n > room ? MSG_TRUNC : 0);
		} else {
			n -= (ssize_t)sizeof(hdr);
		}
		frame_meta(cs, user, headed ? &hdr : NULL, msg.msg_controllen, controllen, native_flags);
		/* as raw_recvmsg: the copied length, MSG_TRUNC set when the frame was cut */
		return (size_t)n > room ? (ssize_t)room : n;
	}
}

PUBLIC ssize_t recvmsg(int fd, struct msghdr *msg, int flags)
{
	struct csock *cs = lookup(fd);
	if (!cs)
		return get_recvmsg()(fd, msg, flags);
	ssize_t n = can_recvmsg(cs, fd, msg, flags);
	return n < 0 && forget_if_stale(fd, cs) ? get_recvmsg()(fd, msg, flags) : n;
}

static ssize_t can_recv_buf(struct csock *cs, int fd, void *buf, size_t len, int flags, struct sockaddr *addr,
			    socklen_t *addrlen)
{
	struct iovec iov = { .iov_base = buf, .iov_len = len };
	struct msghdr msg = { .msg_iov = &iov, .msg_iovlen = 1, .msg_name = addr,
			      .msg_namelen = addrlen ? *addrlen : 0 };
	if (!addrlen)
		msg.msg_name = NULL;
	ssize_t n = can_recvmsg(cs, fd, &msg, flags);
	if (n >= 0 && addrlen)
		*addrlen = msg.msg_namelen;
	return n;
}

PUBLIC ssize_t recvfrom(int fd, void *buf, size_t len, int flags, struct sockaddr *addr, socklen_t *addrlen)
{
	struct csock *cs = lookup(fd);
	if (!cs)
		return get_recvfrom()(fd, buf, len, flags, addr, addrlen);
	ssize_t n = can_recv_buf(cs, fd, buf, len, flags, addr, addrlen);
	return n < 0 && forget_if_stale(fd, cs) ? get_recvfrom()(fd, buf, len, flags, addr, addrlen) : n;
}

PUBLIC ssize_t recv(int fd, void *buf, size_t len, int flags)
{
	struct csock *cs = lookup(fd);
	if (!cs)
		return get_recv()(fd, buf, len, flags);
	ssize_t n = can_recv_buf(cs, fd, buf, len, flags, NULL, NULL);
	return n < 0 && forget_if_stale(fd, cs) ? get_recv()(fd, buf, len, flags) : n;
}

PUBLIC ssize_t read(int fd, void *buf, size_t len)
{
	struct csock *cs = lookup(fd);
	if (!cs)
		return get_read()(fd, buf, len);
	ssize_t n = can_recv_buf(cs, fd, buf, len, 0, NULL, NULL);
	return n < 0 && forget_if_stale(fd, cs) ? get_read()(fd, buf, len) : n;
}

PUBLIC ssize_t readv(int fd, const struct iovec *iov, int iovcnt)
{
	struct csock *cs = lookup(fd);
	if (!cs)
		return get_readv()(fd, iov, iovcnt);
	if (iovcnt < 0) {
		errno = EINVAL;
		return -1;
	}
	struct msghdr msg = { .msg_iov = (struct iovec *)iov, .msg_iovlen = (size_t)iovcnt };
	ssize_t n = can_recvmsg(cs, fd, &msg, 0);
	return n < 0 && forget_if_stale(fd, cs) ? get_readv()(fd, iov, iovcnt) : n;
}

/* recvmmsg: up to MMSG_CHUNK hub messages per real recvmmsg on the unix
 * socket, which gives the kernel's semantics for free (MSG_WAITFORONE,
 * MSG_DONTWAIT, O_NONBLOCK, SO_RCVTIMEO, the timeout checked after each
 * message and written back). Messages land in the library's buffers, are
 * stripped of their header and copied to the program's, control replies
 * skipped. The unix socket's own control data is not passed on: the library
 * asks for none (stamps come from the hub's header). */
#define MMSG_CHUNK 64
#define MMSG_FIRST_MIN 4 /* a first read sized twice the last call's frames, at least this */
#define RX_MSG_MAX (sizeof(struct ucan_rxhdr) + CANFD_MTU)

/* One hub message into the program's mmsghdr; 0 if it was a control reply (skipped). */
static int mmsg_deliver(struct csock *cs, struct mmsghdr *out, const uint8_t *data, size_t len, int native_flags)
{
	if (len == sizeof(struct ucan_ctl))
		return 0; /* a control reply: frames are told by length */
	struct ucan_rxhdr hdr;
	int headed = !bare_frame_len(len);
	if (headed) {
		if (len < sizeof(hdr))
			return 0; /* not a frame the hub sends */
		memcpy(&hdr, data, sizeof(hdr));
		data += sizeof(hdr);
		len -= sizeof(hdr);
	}
	struct msghdr *user = &out->msg_hdr;
	size_t room = iov_total(user->msg_iov, user->msg_iovlen);
	iov_scatter(user->msg_iov, user->msg_iovlen, data, len < room ? len : room);
	if (len > room)
		native_flags |= MSG_TRUNC;
	frame_meta(cs, user, headed ? &hdr : NULL, 0, user->msg_controllen, native_flags);
	out->msg_len = (unsigned)(len > room ? room : len); /* as raw_recvmsg: the copied length */
	return 1;
}

static int can_recvmmsg(struct csock *cs, int fd, struct mmsghdr *vec, unsigned vlen, int flags,
			struct timespec *timeout)
{
	if (timeout && (timeout->tv_sec < 0 || timeout->tv_nsec < 0 || timeout->tv_nsec >= 1000000000)) {
		errno = EINVAL; /* poll_select_set_timeout */
		return -1;
	}
	if (vlen > UIO_MAXIOV)
		vlen = UIO_MAXIOV;
	if (vlen == 0)
		return 0;
	if (!cs->bound && !cs->connected)
		return recv_nothing(fd, flags);
	if (flags & MSG_PEEK) { /* every message is the same first frame: one at a time */
		unsigned i;
		for (i = 0; i < vlen; i++) {
			ssize_t n = can_recvmsg(cs, fd, &vec[i].msg_hdr, flags & ~MSG_WAITFORONE);
			if (n < 0)
				return i ? (int)i : -1;
			vec[i].msg_len = (unsigned)n;
		}
		return (int)i;
	}
	uint8_t buf[MMSG_CHUNK][RX_MSG_MAX];
	struct iovec iov[MMSG_CHUNK];
	struct mmsghdr raw[MMSG_CHUNK];
	unsigned got = 0;
	/* the first read asks for about what came last time: setting up 64 messages for the one
	 * that is there cost more than the frame (callgrind: ~2400 instructions a call) */
	unsigned first = 2 * atomic_load_explicit(&cs->mmsg_last, memory_order_relaxed);
	first = first < MMSG_FIRST_MIN ? MMSG_FIRST_MIN : first > MMSG_CHUNK ? MMSG_CHUNK : first;
	if (!(flags & (MSG_DONTWAIT | MSG_WAITFORONE)))
		first = MMSG_CHUNK; /* it waits for vlen messages anyway */
	while (got < vlen) {
		unsigned chunk = got ? MMSG_CHUNK : first;
		unsigned ask = vlen - got < chunk ? vlen - got : chunk;
		memset(raw, 0, ask * sizeof(raw[0]));
		for (unsigned k = 0; k < ask; k++) {
			iov[k] = (struct iovec){ .iov_base = buf[k], .iov_len = sizeof(buf[k]) };
			raw[k].msg_hdr.msg_iov = &iov[k];
			raw[k].msg_hdr.msg_iovlen = 1;
		}
		int rflags = flags & ~MSG_TRUNC;
		if (got && (flags & MSG_WAITFORONE))
			rflags |= MSG_DONTWAIT;
		int r = get_recvmmsg()(fd, raw, ask, rflags, timeout);
		if (r < 0) {
			if (got)
				break; /* the kernel returns what it has; the error shows on the next call */
			if (errno == ECONNRESET || errno == EPIPE || errno == ENOTCONN)
				errno = ENETDOWN;
			return -1;
		}
		for (int k = 0; k < r; k++) {
			if (raw[k].msg_len == 0) { /* hub went away: like an interface going down */
				if (got)
					return (int)got;
				errno = ENETDOWN;
				return -1;
			}
			got += (unsigned)mmsg_deliver(cs, &vec[got], buf[k], raw[k].msg_len, raw[k].msg_hdr.msg_flags);
		}
		if (got == 0)
			continue; /* only control replies: still waiting for the first frame */
		if ((unsigned)r < ask || (timeout && timeout->tv_sec == 0 && timeout->tv_nsec == 0))
			break; /* the kernel stopped early: nothing more now, or the timeout ran out */
	}
	atomic_store_explicit(&cs->mmsg_last, got, memory_order_relaxed);
	return (int)got;
}

PUBLIC int recvmmsg(int fd, struct mmsghdr *vec, unsigned vlen, int flags, struct timespec *timeout)
{
	struct csock *cs = lookup(fd);
	if (!cs)
		return get_recvmmsg()(fd, vec, vlen, flags, timeout);
	int n = can_recvmmsg(cs, fd, vec, vlen, flags, timeout);
	return n < 0 && forget_if_stale(fd, cs) ? get_recvmmsg()(fd, vec, vlen, flags, timeout) : n;
}

/* fortified variants used by programs built with _FORTIFY_SOURCE */
PUBLIC ssize_t __read_chk(int fd, void *buf, size_t len, size_t buflen)
{
	if (len > buflen)
		abort();
	return read(fd, buf, len);
}

PUBLIC ssize_t __recv_chk(int fd, void *buf, size_t len, size_t buflen, int flags)
{
	if (len > buflen)
		abort();
	return recv(fd, buf, len, flags);
}

PUBLIC ssize_t __recvfrom_chk(int fd, void *buf, size_t len, size_t buflen, int flags, struct sockaddr *addr,
			      socklen_t *addrlen)
{
	if (len > buflen)
		abort();
	return recvfrom(fd, buf, len, flags, addr, addrlen);
}

/* ---- sending ---- */

/* Validates one frame the program sends and builds its hub message in msg
 * (ucan_txhdr + frame); returns the frame's size, or -1 with the kernel's errno.
 * *paced: the interface emulates a wire (bitrate=). */
static ssize_t tx_build(struct csock *cs, const struct iovec *iov, size_t iovlen, const struct sockaddr *addr,
			socklen_t addrlen, uint8_t msg[sizeof(struct ucan_txhdr) + CANFD_MTU], int *paced)
{
	uint32_t ifindex = cs->opts.ifindex;
	if (addr) {
		const struct sockaddr_can *can = (const struct sockaddr_can *)addr;
		if (addrlen < offsetof(struct sockaddr_can, can_addr) || can->can_family != AF_CAN) {
			errno = EINVAL;
			return -1;
		}
		ifindex = (uint32_t)can->can_ifindex;
	}
	size_t size = iov_total(iov, iovlen);
	if (size != CAN_MTU && size != CANFD_MTU) {
		errno = EINVAL;
		return -1;
	}
	struct ucan_ifinfo ifi;
	if (ifindex == 0 || find_iface(NULL, ifindex, &ifi) < 0) {
		errno = ENXIO;
		return -1;
	}
	struct ucan_txhdr hdr = { .type = UCAN_MSG_FRAME, .ifindex = ifindex };
	memcpy(msg, &hdr, sizeof(hdr));
	iov_gather(iov, iovlen, msg + sizeof(hdr), size);
	struct canfd_frame frame;
	memcpy(&frame, msg + sizeof(hdr), size);
	if (size == CAN_MTU ? frame.len > CAN_MAX_DLEN
			    : (!cs->opts.fd_frames || ifi.mtu != CANFD_MTU || frame.len > CANFD_MAX_DLEN)) {
		errno = EINVAL;
		return -1;
	}
	*paced = ifi.bitrate != 0;
	return (ssize_t)size;
}

static int tx_connect(struct csock *cs, int fd)
{
	if (cs->connected)
		return 0;
	pthread_mutex_lock(&cs->lock);
	int rc = ensure_connected(cs, fd);
	pthread_mutex_unlock(&cs->lock);
	return rc;
}

static void tx_errno(void)
{
	if (errno == EAGAIN)
		errno = ENOBUFS; /* what a full CAN tx queue reports */
	else if (errno == EPIPE || errno == ECONNRESET || errno == ENOTCONN)
		errno = ENETDOWN;
}

static ssize_t can_send(struct csock *cs, int fd, const struct iovec *iov, size_t iovlen, int flags,
			const struct sockaddr *addr, socklen_t addrlen)
{
	uint8_t msg[sizeof(struct ucan_txhdr) + CANFD_MTU];
	int paced;
	ssize_t size = tx_build(cs, iov, iovlen, addr, addrlen, msg, &paced);
	if (size < 0 || tx_connect(cs, fd) < 0)
		return -1;
	ssize_t n = get_send()(fd, msg, sizeof(struct ucan_txhdr) + (size_t)size, MSG_NOSIGNAL | (flags & MSG_DONTWAIT));
	if (n < 0) {
		tx_errno();
		return -1;
	}
	return size;
}

/* sendmmsg: the frames go to the hub as UCAN_MSG_FRAMES messages, as many per
 * message as UCAN_MSG_MAX holds, one real send each, so a burst costs the
 * program one syscall and the kernel one message per UCAN_MSG_MAX bytes, as
 * a kernel sendmmsg costs one syscall. A frame for a bitrate= interface goes
 * alone, as send() sends it: it waits for the wire anyway, and one message per
 * frame keeps the backpressure a paced sender feels (frames in flight to the
 * hub: the unix socket's send buffer in messages) what it was.
 * As the kernel's: frames go in order; the first that fails (invalid:
 * EINVAL/ENXIO before anything of it is sent; the hub's socket full with
 * MSG_DONTWAIT: ENOBUFS) ends the call, which returns how many went, or -1 if
 * none did. */
#define BATCH_FRAMES_MAX ((UCAN_MSG_MAX - sizeof(struct ucan_txbatch)) / (sizeof(struct ucan_txrec) + CAN_MTU))
static int can_sendmmsg(struct csock *cs, int fd, struct mmsghdr *vec, unsigned vlen, int flags)
{
	if (vlen > UIO_MAXIOV)
		vlen = UIO_MAXIOV;
	uint8_t batch[UCAN_MSG_MAX];
	uint8_t one[sizeof(struct ucan_txhdr) + CANFD_MTU];
	uint8_t sizes[BATCH_FRAMES_MAX];
	unsigned sent = 0;
	while (sent < vlen) {
		/* a small SO_SNDBUF refuses a long message (EMSGSIZE): halved until it fits */
		unsigned limit = atomic_load(&cs->batch_bytes);
		limit = limit ? limit : UCAN_MSG_MAX;
		if (vlen - sent == 1) { /* one frame left: the message send() sends, built in place */
			const struct msghdr *m = &vec[sent].msg_hdr;
			ssize_t size = can_send(cs, fd, m->msg_iov, m->msg_iovlen, flags, m->msg_name, m->msg_namelen);
			if (size < 0)
				return sent ? (int)sent : -1;
			vec[sent].msg_len = (unsigned)size;
			return (int)sent + 1;
		}
		size_t used = sizeof(struct ucan_txbatch);
		unsigned k = 0;
		int bad = 0, paced = 0;
		while (sent + k < vlen && (k == 0 || used + sizeof(struct ucan_txrec) + CANFD_MTU <= limit)) {
			const struct msghdr *m = &vec[sent + k].msg_hdr;
			ssize_t size = tx_build(cs, m->msg_iov, m->msg_iovlen, m->msg_name, m->msg_namelen, one, &paced);
			if (size < 0) {
				bad = errno;
				break;
			}
			if (paced && k > 0)
				break; /* sent alone, next round */
			struct ucan_txhdr hdr;
			memcpy(&hdr, one, sizeof(hdr));
			struct ucan_txrec rec = { .ifindex = hdr.ifindex, .size = (uint32_t)size };
			memcpy(batch + used, &rec, sizeof(rec));
			memcpy(batch + used + sizeof(rec), one + sizeof(hdr), (size_t)size);
			used += sizeof(rec) + (size_t)size;
			sizes[k++] = (uint8_t)size;
			if (paced)
				break;
		}
		if (k) {
			if (tx_connect(cs, fd) < 0)
				return sent ? (int)sent : -1;
			ssize_t r;
			if (k == 1) { /* alone (paced, or the next is invalid or would not fit): as send() */
				const struct msghdr *m = &vec[sent].msg_hdr;
				r = can_send(cs, fd, m->msg_iov, m->msg_iovlen, flags, m->msg_name, m->msg_namelen);
			} else {
				struct ucan_txbatch head = { .type = UCAN_MSG_FRAMES, .count = k };
				memcpy(batch, &head, sizeof(head));
				r = get_send()(fd, batch, used, MSG_NOSIGNAL | (flags & MSG_DONTWAIT));
				if (r < 0 && errno == EMSGSIZE) {
					atomic_store(&cs->batch_bytes, (unsigned)used / 2);
					continue; /* nothing of it went: the same frames again, fewer per message */
				}
			}
			if (r < 0) {
				tx_errno();
				return sent ? (int)sent : -1;
			}
			for (unsigned i = 0; i < k; i++)
				vec[sent + i].msg_len = sizes[i];
			sent += k;
		}
		if (bad) {
			errno = bad;
			return sent ? (int)sent : -1;
		}
	}
	return (int)sent;
}

PUBLIC ssize_t sendmsg(int fd, const struct msghdr *msg, int flags)
{
	struct csock *cs = lookup(fd);
	if (!cs)
		return get_sendmsg()(fd, msg, flags);
	ssize_t n = can_send(cs, fd, msg->msg_iov, msg->msg_iovlen, flags, msg->msg_name, msg->msg_namelen);
	return n < 0 && forget_if_stale(fd, cs) ? get_sendmsg()(fd, msg, flags) : n;
}

PUBLIC ssize_t sendto(int fd, const void *buf, size_t len, int flags, const struct sockaddr *addr, socklen_t addrlen)
{
	struct csock *cs = lookup(fd);
	if (!cs)
		return get_sendto()(fd, buf, len, flags, addr, addrlen);
	struct iovec iov = { .iov_base = (void *)buf, .iov_len = len };
	ssize_t n = can_send(cs, fd, &iov, 1, flags, addr, addrlen);
	return n < 0 && forget_if_stale(fd, cs) ? get_sendto()(fd, buf, len, flags, addr, addrlen) : n;
}

PUBLIC ssize_t send(int fd, const void *buf, size_t len, int flags)
{
	struct csock *cs = lookup(fd);
	if (!cs)
		return get_send()(fd, buf, len, flags);
	struct iovec iov = { .iov_base = (void *)buf, .iov_len = len };
	ssize_t n = can_send(cs, fd, &iov, 1, flags, NULL, 0);
	return n < 0 && forget_if_stale(fd, cs) ? get_send()(fd, buf, len, flags) : n;
}

PUBLIC ssize_t write(int fd, const void *buf, size_t len)
{
	struct csock *cs = lookup(fd);
	if (!cs)
		return get_write()(fd, buf, len);
	struct iovec iov = { .iov_base = (void *)buf, .iov_len = len };
	ssize_t n = can_send(cs, fd, &iov, 1, 0, NULL, 0);
	return n < 0 && forget_if_stale(fd, cs) ? get_write()(fd, buf, len) : n;
}

PUBLIC ssize_t writev(int fd, const struct iovec *iov, int iovcnt)
{
	struct csock *cs = lookup(fd);
	if (!cs)
		return get_writev()(fd, iov, iovcnt);
	if (iovcnt < 0) {
		errno = EINVAL;
		return -1;
	}
	ssize_t n = can_send(cs, fd, iov, (size_t)iovcnt, 0, NULL, 0);
	return n < 0 && forget_if_stale(fd, cs) ? get_writev()(fd, iov, iovcnt) : n;
}

PUBLIC int sendmmsg(int fd, struct mmsghdr *vec, unsigned vlen, int flags)
{
	struct csock *cs = lookup(fd);
	if (!cs)
		return get_sendmmsg()(fd, vec, vlen, flags);
	int n = can_sendmmsg(cs, fd, vec, vlen, flags);
	return n < 0 && forget_if_stale(fd, cs) ? get_sendmmsg()(fd, vec, vlen, flags) : n;
}

/* ---- inherited sockets ---- */

/* A CAN socket inherited across exec is still connected to the hub; find it
 * by its abstract name and ask the hub for its settings. */
static void adopt_inherited(int fd)
{
	struct sockaddr_un addr;
	socklen_t len = sizeof(addr);
	size_t prefix = strlen(UCAN_COOKIE_PREFIX);
	if (get_getsockname()(fd, (struct sockaddr *)&addr, &len) < 0 || addr.sun_family != AF_UNIX)
		return;
	size_t name_len = len > offsetof(struct sockaddr_un, sun_path) + 1
				  ? len - offsetof(struct sockaddr_un, sun_path) - 1
				  : 0;
	if (addr.sun_path[0] != '\0' || name_len <= prefix || name_len >= UCAN_COOKIE_MAX ||
	    memcmp(addr.sun_path + 1, UCAN_COOKIE_PREFIX, prefix) != 0)
		return;
	struct csock *cs = calloc(1, sizeof(*cs));
	if (!cs)
		return;
	pthread_mutex_init(&cs->lock, NULL);
	default_opts(cs);
	memcpy(cs->cookie, addr.sun_path + 1, name_len);
	remember_identity(fd, cs);
	struct sockaddr_un peer;
	socklen_t peer_len = sizeof(peer);
	cs->connected = get_getpeername()(fd, (struct sockaddr *)&peer, &peer_len) == 0;
	if (cs->connected) {
		struct ucan_barrier req = { .type = UCAN_MSG_GETOPT };
		uint8_t reply[sizeof(struct ucan_sockopts) + sizeof(cs->filters)];
		memcpy(req.cookie, cs->cookie, sizeof(req.cookie));
		ssize_t n = hub_query(&req, sizeof(req), reply, sizeof(reply));
		struct ucan_sockopts opts;
		if (n >= (ssize_t)sizeof(opts)) {
			memcpy(&opts, reply, sizeof(opts));
			if (opts.type == UCAN_MSG_GETOPT && opts.nfilters <= UCAN_MAX_FILTERS &&
			    (size_t)n == sizeof(opts) + opts.nfilters * sizeof(struct can_filter)) {
				cs->bound = opts.bound;
				memcpy(cs->filters, reply + sizeof(opts), opts.nfilters * sizeof(struct can_filter));
				opts.bound = opts.header_mode = 0;
				cs->opts = opts;
				cs->ioctl_stamps = opts.timestamps == UCAN_TS_IOCTL;
			}
		}
	}
	if (track(fd, cs) < 0) {
		pthread_mutex_destroy(&cs->lock);
		free(cs);
	}
}

/* fork() copies only the calling thread: a lock another thread held would
 * stay locked in the child forever. The library's global locks are taken
 * across fork (held only for table and cache updates, never across a hub
 * query); each socket's lock, which a thread may hold while it waits for the
 * hub, starts afresh in the child. */
static void atfork_prepare(void)
{
	pthread_mutex_lock(&table_lock);
	pthread_mutex_lock(&iflist_lock);
}

static void atfork_parent(void)
{
	pthread_mutex_unlock(&iflist_lock);
	pthread_mutex_unlock(&table_lock);
}

static void atfork_child(void)
{
	pthread_mutex_unlock(&iflist_lock);
	pthread_mutex_unlock(&table_lock);
	for (unsigned c = 0; c < FD_CHUNKS; c++) {
		_Atomic(struct csock *) *chunk = (void *)fd_chunks[c];
		for (unsigned i = 0; chunk && i < (1u << FD_CHUNK_BITS); i++) {
			struct csock *cs = atomic_load(&chunk[i]);
			if (cs)
				pthread_mutex_init(&cs->lock, NULL);
		}
	}
}

__attribute__((constructor)) static void ucan_init(void)
{
	pthread_atfork(atfork_prepare, atfork_parent, atfork_child);
	DIR *dir = opendir("/proc/self/fd");
	if (!dir)
		return;
	int self = dirfd(dir);
	struct dirent *de;
	while ((de = readdir(dir)) != NULL) {
		char *end;
		long fd = strtol(de->d_name, &end, 10);
		if (*end || fd == self || de->d_name[0] == '.')
			continue;
		int type;
		socklen_t len = sizeof(type);
		if (get_getsockopt()((int)fd, SOL_SOCKET, SO_TYPE, &type, &len) == 0 && type == SOCK_SEQPACKET)
			adopt_inherited((int)fd);
	}
	closedir(dir);
}
