/* mmsg_probe - recvmmsg/sendmmsg on CAN_RAW sockets as the kernel defines
 * them (net/socket.c do_recvmmsg/__sys_sendmmsg, net/can/raw.c), for the bus
 * conformance suite: the same checks hold on kernel vcan and on the
 * userspace hub (tests/bus/test_mmsg.py).
 *
 * Usage: mmsg_probe checks <iface>     every semantic check, one "ok:" or "FAIL:" line each
 *        mmsg_probe burst <iface> <n>  n frames with one sendmmsg, back with one blocking
 *                                      recvmmsg; write(-1, "burst-start") and "burst-end"
 *                                      mark it, so a tracer can count the syscalls it took
 *
 * "Settled": frames are sent on one socket and a witness socket reads them
 * with plain read(), then sets a CAN_RAW option (on the hub a round trip: the
 * option is applied before setsockopt returns, so the hub's round that
 * delivered the frames to every reader has ended; on the kernel delivery
 * happens inside send()): every other reader has them queued. */
#define _GNU_SOURCE
#include <errno.h>
#include <net/if.h>
#include <pthread.h>
#include <sched.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <sys/syscall.h>
#include <sys/time.h>
#include <time.h>
#include <unistd.h>
#include <linux/can.h>
#include <linux/can/raw.h>

#define VLEN_MAX 512
#define WAIT_SLEEPING_S 5 /* how long the sender thread waits to see the reader blocked */
#define PROBE_TIMEOUT_S 15 /* a call that blocks where the kernel's would not: SIGALRM ends the probe */

static int failures;
static int ifindex;

#define CHECK(cond, ...)                                                                                               \
	do {                                                                                                           \
		if (cond) {                                                                                            \
			printf("ok: ");                                                                                \
		} else {                                                                                               \
			printf("FAIL: %s:%d: ", __FILE__, __LINE__);                                                   \
			failures++;                                                                                    \
		}                                                                                                      \
		printf(__VA_ARGS__);                                                                                   \
		printf("\n");                                                                                          \
		fflush(stdout);                                                                                        \
	} while (0)

static int open_can(int index)
{
	int s = socket(PF_CAN, SOCK_RAW, CAN_RAW);
	struct sockaddr_can addr = { .can_family = AF_CAN, .can_ifindex = index };
	if (s < 0 || bind(s, (struct sockaddr *)&addr, sizeof(addr)) < 0) {
		perror("socket/bind");
		exit(1);
	}
	return s;
}

static struct can_frame frame_of(canid_t id)
{
	struct can_frame f;
	memset(&f, 0, sizeof(f));
	f.can_id = id;
	f.len = 2;
	f.data[0] = (uint8_t)(id >> 8);
	f.data[1] = (uint8_t)id;
	return f;
}

/* A receive vector of n messages, each a can_frame and room for two stamps. */
struct rxvec {
	struct mmsghdr m[VLEN_MAX];
	struct iovec iov[VLEN_MAX];
	struct can_frame f[VLEN_MAX];
	char ctl[VLEN_MAX][CMSG_SPACE(sizeof(struct timespec)) * 2];
	struct sockaddr_can name[VLEN_MAX];
};

static void rxvec_init(struct rxvec *v, unsigned n, size_t frame_room, size_t ctl_room)
{
	memset(v, 0, sizeof(*v));
	for (unsigned i = 0; i < n; i++) {
		v->iov[i] = (struct iovec){ .iov_base = &v->f[i], .iov_len = frame_room };
		v->m[i].msg_hdr.msg_iov = &v->iov[i];
		v->m[i].msg_hdr.msg_iovlen = 1;
		v->m[i].msg_hdr.msg_control = ctl_room ? v->ctl[i] : NULL;
		v->m[i].msg_hdr.msg_controllen = ctl_room;
		v->m[i].msg_len = 12345; /* must be overwritten */
	}
}

static int send_frames(int s, const canid_t *ids, unsigned n)
{
	static struct mmsghdr m[VLEN_MAX];
	static struct iovec iov[VLEN_MAX];
	static struct can_frame f[VLEN_MAX];
	memset(m, 0, sizeof(m));
	for (unsigned i = 0; i < n; i++) {
		f[i] = frame_of(ids[i]);
		iov[i] = (struct iovec){ .iov_base = &f[i], .iov_len = sizeof(f[i]) };
		m[i].msg_hdr.msg_iov = &iov[i];
		m[i].msg_hdr.msg_iovlen = 1;
	}
	return sendmmsg(s, m, n, 0);
}

static void round_trip(int witness)
{
	can_err_mask_t none = 0;
	if (setsockopt(witness, SOL_CAN_RAW, CAN_RAW_ERR_FILTER, &none, sizeof(none)) < 0) {
		perror("setsockopt (round trip)");
		exit(1);
	}
}

/* Sends n frames from id on tx, then reads them on the witness: settled. */
static void settle(int tx, int witness, canid_t id, unsigned n)
{
	canid_t ids[VLEN_MAX];
	for (unsigned i = 0; i < n; i++)
		ids[i] = id + i;
	if (send_frames(tx, ids, n) != (int)n) {
		perror("sendmmsg (settle)");
		exit(1);
	}
	for (unsigned i = 0; i < n; i++) {
		struct can_frame f;
		if (read(witness, &f, sizeof(f)) != sizeof(f) || f.can_id != id + i) {
			fprintf(stderr, "witness: frame %u of %u not 0x%X\n", i, n, id + i);
			exit(1);
		}
	}
	round_trip(witness);
}

static int64_t ts_ns(const struct timespec *t)
{
	return (int64_t)t->tv_sec * 1000000000 + t->tv_nsec;
}

static int64_t now_ns(void)
{
	struct timespec t;
	clock_gettime(CLOCK_REALTIME, &t);
	return ts_ns(&t);
}

/* ---- the reader blocked while a thread sends the rest ---- */

struct late_sender {
	int tx;
	pid_t reader_tid;
	volatile int reading;
	int sent;
};

static char thread_state(pid_t tid)
{
	char path[64], buf[512];
	snprintf(path, sizeof(path), "/proc/self/task/%d/stat", (int)tid);
	FILE *f = fopen(path, "r");
	if (!f)
		return '?';
	size_t n = fread(buf, 1, sizeof(buf) - 1, f);
	fclose(f);
	buf[n] = 0;
	char *p = strrchr(buf, ')'); /* "pid (comm) S ..." */
	return p && p[1] == ' ' ? p[2] : '?';
}

static void *send_when_blocked(void *arg)
{
	struct late_sender *ls = arg;
	struct timespec tick = { 0, 1000000 };
	for (int i = 0; i < WAIT_SLEEPING_S * 1000; i++) {
		if (ls->reading == 2)
			return NULL; /* the reader returned without waiting for these */
		if (ls->reading == 1 && thread_state(ls->reader_tid) == 'S')
			break;
		nanosleep(&tick, NULL); /* polling the reader's state, not a delay to wait out */
	}
	canid_t ids[2] = { 0x1C0, 0x1C1 };
	ls->sent = send_frames(ls->tx, ids, 2);
	return NULL;
}

static void checks(void)
{
	int tx = open_can(ifindex), witness = open_can(ifindex), rx = open_can(ifindex);
	static struct rxvec v;
	struct timespec t;

	/* nothing queued, MSG_DONTWAIT: EAGAIN */
	rxvec_init(&v, 4, sizeof(struct can_frame), 0);
	errno = 0;
	int n = recvmmsg(rx, v.m, 4, MSG_DONTWAIT, NULL);
	CHECK(n == -1 && errno == EAGAIN, "empty queue, MSG_DONTWAIT: -1 EAGAIN (got %d, %s)", n, strerror(errno));

	/* an invalid timeout: EINVAL before anything is read */
	t = (struct timespec){ 0, 1000000000 };
	errno = 0;
	n = recvmmsg(rx, v.m, 4, MSG_DONTWAIT, &t);
	CHECK(n == -1 && errno == EINVAL, "timeout tv_nsec 1e9: -1 EINVAL (got %d, %s)", n, strerror(errno));

	/* sendmmsg: each message's msg_len is the frame's size */
	canid_t ids[3] = { 0x100, 0x101, 0x102 };
	struct mmsghdr sm[3];
	struct iovec siov[3];
	struct can_frame sf[3];
	memset(sm, 0, sizeof(sm));
	for (int i = 0; i < 3; i++) {
		sf[i] = frame_of(ids[i]);
		siov[i] = (struct iovec){ &sf[i], sizeof(sf[i]) };
		sm[i].msg_hdr.msg_iov = &siov[i];
		sm[i].msg_hdr.msg_iovlen = 1;
	}
	n = sendmmsg(tx, sm, 3, 0);
	CHECK(n == 3 && sm[0].msg_len == CAN_MTU && sm[2].msg_len == CAN_MTU, "sendmmsg of 3: 3, msg_len %d each (got %d, %u)",
	      (int)CAN_MTU, n, sm[2].msg_len);
	for (int i = 0; i < 3; i++) {
		struct can_frame f;
		if (read(witness, &f, sizeof(f)) != sizeof(f))
			exit(1);
	}
	round_trip(witness);

	/* MSG_WAITFORONE: what is queued, in order, msg_len and flags per message */
	rxvec_init(&v, 8, sizeof(struct can_frame), 0);
	n = recvmmsg(rx, v.m, 8, MSG_WAITFORONE, NULL);
	int order = n == 3;
	for (int i = 0; i < n && order; i++)
		order = v.f[i].can_id == ids[i] && v.m[i].msg_len == CAN_MTU &&
			(v.m[i].msg_hdr.msg_flags & (MSG_DONTROUTE | MSG_CONFIRM)) == MSG_DONTROUTE;
	CHECK(order, "MSG_WAITFORONE, 3 queued, vlen 8: 3 in order, msg_len 16, MSG_DONTROUTE (got %d)", n);

	/* MSG_DONTWAIT with frames queued: all of them, then EAGAIN */
	settle(tx, witness, 0x110, 2);
	rxvec_init(&v, 8, sizeof(struct can_frame), 0);
	n = recvmmsg(rx, v.m, 8, MSG_DONTWAIT, NULL);
	CHECK(n == 2 && v.f[1].can_id == 0x111, "MSG_DONTWAIT, 2 queued, vlen 8: 2 (got %d)", n);

	/* a zero timeout is checked after the first message: one returned */
	settle(tx, witness, 0x120, 3);
	t = (struct timespec){ 0, 0 };
	rxvec_init(&v, 4, sizeof(struct can_frame), 0);
	n = recvmmsg(rx, v.m, 4, 0, &t);
	CHECK(n == 1 && v.f[0].can_id == 0x120, "timeout 0, 3 queued, vlen 4: 1 (got %d)", n);
	n = recvmmsg(rx, v.m, 4, MSG_DONTWAIT, NULL);
	CHECK(n == 2 && v.f[0].can_id == 0x121, "the other 2 stay queued (got %d)", n);

	/* the remaining time is written back */
	settle(tx, witness, 0x130, 2);
	t = (struct timespec){ 5, 0 };
	rxvec_init(&v, 2, sizeof(struct can_frame), 0);
	n = recvmmsg(rx, v.m, 2, 0, &t);
	CHECK(n == 2 && t.tv_sec == 4 && t.tv_nsec > 0, "timeout 5 s, 2 queued, vlen 2: 2, remaining 4.x s written back (got %d, %ld.%09ld)",
	      n, (long)t.tv_sec, t.tv_nsec);

	/* blocking without MSG_WAITFORONE: waits until vlen messages came */
	settle(tx, witness, 0x1B0, 2);
	struct late_sender ls = { .tx = tx, .reader_tid = (pid_t)syscall(SYS_gettid) };
	pthread_t th;
	pthread_create(&th, NULL, send_when_blocked, &ls);
	rxvec_init(&v, 4, sizeof(struct can_frame), 0);
	ls.reading = 1;
	n = recvmmsg(rx, v.m, 4, 0, NULL);
	ls.reading = 2;
	pthread_join(th, NULL);
	CHECK(n == 4 && v.f[3].can_id == 0x1C1, "blocking, 2 queued, 2 sent while it waits, vlen 4: 4 (got %d)", n);
	if (n != 4 && ls.sent == 2) /* drain what the late sender sent, or the next checks see it */
		for (int i = 0; i < 2; i++)
			read(rx, &v.f[0], sizeof(v.f[0]));
	for (int i = 0; i < 2 && ls.sent == 2; i++)
		read(witness, &v.f[0], sizeof(v.f[0]));

	/* a buffer smaller than the frame: the copied bytes, MSG_TRUNC */
	settle(tx, witness, 0x140, 1);
	rxvec_init(&v, 1, 8, 0);
	n = recvmmsg(rx, v.m, 1, 0, NULL);
	CHECK(n == 1 && v.m[0].msg_len == 8 && (v.m[0].msg_hdr.msg_flags & MSG_TRUNC) && v.f[0].can_id == 0x140,
	      "8-byte buffer: msg_len 8, MSG_TRUNC (got %d, %u, flags 0x%x)", n, v.m[0].msg_len, v.m[0].msg_hdr.msg_flags);

	/* the same with recv(): 8 bytes, not mistaken for anything else (the library's control
	 * replies are 8 bytes long) */
	settle(tx, witness, 0x141, 1);
	char eight[8];
	n = (int)recv(rx, eight, sizeof(eight), MSG_DONTWAIT);
	canid_t id8;
	memcpy(&id8, eight, sizeof(id8));
	CHECK(n == 8 && id8 == 0x141, "recv() into 8 bytes: 8, the frame's first 8 bytes (got %d, 0x%X)", n, id8);

	/* per-message stamps: SO_TIMESTAMPNS and SO_TIMESTAMP, one control message each */
	int rxns = open_can(ifindex), rxus = open_can(ifindex), on = 1;
	setsockopt(rxns, SOL_SOCKET, SO_TIMESTAMPNS, &on, sizeof(on));
	setsockopt(rxus, SOL_SOCKET, SO_TIMESTAMP, &on, sizeof(on));
	int64_t before = now_ns();
	settle(tx, witness, 0x150, 3);
	for (int kind = 0; kind < 2; kind++) {
		int s = kind ? rxus : rxns;
		int want = kind ? SCM_TIMESTAMP : SCM_TIMESTAMPNS;
		size_t want_len = kind ? CMSG_SPACE(sizeof(struct timeval)) : CMSG_SPACE(sizeof(struct timespec));
		rxvec_init(&v, 3, sizeof(struct can_frame), sizeof(v.ctl[0]));
		n = recvmmsg(s, v.m, 3, 0, NULL);
		int64_t after = now_ns(), last = 0;
		int good = n == 3;
		for (int i = 0; i < n && good; i++) {
			struct msghdr *h = &v.m[i].msg_hdr;
			struct cmsghdr *c = CMSG_FIRSTHDR(h);
			good = h->msg_controllen == want_len && c && c->cmsg_level == SOL_SOCKET && c->cmsg_type == want &&
			       !CMSG_NXTHDR(h, c) && !(h->msg_flags & MSG_CTRUNC);
			if (!good)
				break;
			int64_t stamp;
			if (kind) {
				struct timeval tv;
				memcpy(&tv, CMSG_DATA(c), sizeof(tv));
				stamp = (int64_t)tv.tv_sec * 1000000000 + tv.tv_usec * 1000;
			} else {
				struct timespec ts;
				memcpy(&ts, CMSG_DATA(c), sizeof(ts));
				stamp = ts_ns(&ts);
			}
			good = stamp >= before - 1000 && stamp <= after && stamp >= last;
			last = stamp;
		}
		CHECK(good, "%s: one %s per message, between send and receipt, never decreasing (got %d)",
		      kind ? "SO_TIMESTAMP" : "SO_TIMESTAMPNS", kind ? "SCM_TIMESTAMP" : "SCM_TIMESTAMPNS", n);
	}
	/* control room too small for the stamp: MSG_CTRUNC, no whole stamp (put_cmsg may leave a
	 * cut header in the room there is; the library leaves none) */
	settle(tx, witness, 0x160, 1);
	rxvec_init(&v, 1, sizeof(struct can_frame), sizeof(struct cmsghdr));
	n = recvmmsg(rxns, v.m, 1, 0, NULL);
	struct cmsghdr *cut = v.m[0].msg_hdr.msg_controllen ? CMSG_FIRSTHDR(&v.m[0].msg_hdr) : NULL;
	CHECK(n == 1 && (v.m[0].msg_hdr.msg_flags & MSG_CTRUNC) && v.m[0].msg_hdr.msg_controllen <= sizeof(struct cmsghdr) &&
		      (!cut || cut->cmsg_len < CMSG_LEN(sizeof(struct timespec))),
	      "control room 16 bytes: MSG_CTRUNC, no whole stamp (got %d, flags 0x%x, %zu)", n,
	      v.m[0].msg_hdr.msg_flags, (size_t)v.m[0].msg_hdr.msg_controllen);
	recvmmsg(rxus, v.m, 1, 0, NULL);

	/* bound to any: msg_name names the interface of each message */
	int any = open_can(0);
	settle(tx, witness, 0x170, 2);
	rxvec_init(&v, 2, sizeof(struct can_frame), 0);
	for (int i = 0; i < 2; i++) {
		v.m[i].msg_hdr.msg_name = &v.name[i];
		v.m[i].msg_hdr.msg_namelen = sizeof(v.name[i]);
	}
	n = recvmmsg(any, v.m, 2, 0, NULL);
	CHECK(n == 2 && v.name[1].can_family == AF_CAN && v.name[1].can_ifindex == ifindex &&
		      v.m[1].msg_hdr.msg_namelen == 8,
	      "bound to any: msg_name AF_CAN, ifindex %d, msg_namelen 8 (got %d, %d, %u)", ifindex, n,
	      v.name[1].can_ifindex, (unsigned)v.m[1].msg_hdr.msg_namelen);

	/* sendmmsg stops at an invalid message: the ones before it sent, the call after it fails */
	int rx2 = open_can(ifindex);
	struct can_frame good_f[2] = { frame_of(0x180), frame_of(0x181) };
	char bad[10] = { 0 };
	struct iovec biov[3] = { { &good_f[0], sizeof(good_f[0]) }, { bad, sizeof(bad) }, { &good_f[1], sizeof(good_f[1]) } };
	memset(sm, 0, sizeof(sm));
	for (int i = 0; i < 3; i++) {
		sm[i].msg_hdr.msg_iov = &biov[i];
		sm[i].msg_hdr.msg_iovlen = 1;
	}
	n = sendmmsg(tx, sm, 3, 0);
	errno = 0;
	int n2 = sendmmsg(tx, sm + 1, 2, 0);
	int err2 = errno;
	struct can_frame f;
	read(witness, &f, sizeof(f));
	canid_t first = f.can_id;
	settle(tx, witness, 0x18F, 1); /* a marker: had 0x181 gone, it would come first */
	rxvec_init(&v, 2, sizeof(struct can_frame), 0);
	int got = recvmmsg(rx2, v.m, 2, 0, NULL);
	CHECK(n == 1 && n2 == -1 && err2 == EINVAL && first == 0x180 && got == 2 && v.f[1].can_id == 0x18F,
	      "sendmmsg [valid, 10 bytes, valid]: 1; the rest: -1 EINVAL; only the first on the bus (got %d, %d %s, "
	      "0x%X, then 0x%X)",
	      n, n2, strerror(err2), first, v.f[1].can_id);

	/* a small SO_SNDBUF (the kernel's floor) still takes a long burst: over the hub the
	 * preload's batch message shrinks until the socket takes it, not EMSGSIZE */
	int small_tx = open_can(ifindex), rx3 = open_can(ifindex), tiny = 1024;
	setsockopt(small_tx, SOL_SOCKET, SO_SNDBUF, &tiny, sizeof(tiny));
	enum { SMALL_BUF_BURST = 200 };
	canid_t sb_ids[SMALL_BUF_BURST];
	for (int i = 0; i < SMALL_BUF_BURST; i++)
		sb_ids[i] = 0x400 + (canid_t)i;
	int sb_sent = send_frames(small_tx, sb_ids, SMALL_BUF_BURST);
	int sb_err = errno, sb_order = 1;
	for (int i = 0; i < SMALL_BUF_BURST && sb_order && sb_sent == SMALL_BUF_BURST; i++)
		sb_order = read(rx3, &f, sizeof(f)) == sizeof(f) && f.can_id == sb_ids[i];
	CHECK(sb_sent == SMALL_BUF_BURST && sb_order, "SO_SNDBUF 1024, sendmmsg of %d: all, in order (got %d, %s)",
	      SMALL_BUF_BURST, sb_sent, sb_sent < 0 ? strerror(sb_err) : "ok");
	close(small_tx);
	close(rx3);

	close(any);
	close(rx2);
	close(rxns);
	close(rxus);
	close(rx);
	close(witness);
	close(tx);
}

#define MARK(what) (void)!write(-1, what, sizeof(what) - 1)

static void burst(unsigned n)
{
	int tx = open_can(ifindex), rx = open_can(ifindex);
	int rcvbuf = 1 << 20; /* kernel vcan: n frames must fit the socket's queue */
	setsockopt(rx, SOL_SOCKET, SO_RCVBUF, &rcvbuf, sizeof(rcvbuf));
	canid_t ids[VLEN_MAX];
	for (unsigned i = 0; i < n; i++)
		ids[i] = 0x300 + i;
	static struct rxvec v;
	rxvec_init(&v, n, sizeof(struct can_frame), 0);
	MARK("burst-start"); /* a failing write a tracer shows: the burst starts here */
	int sent = send_frames(tx, ids, n);
	int got = recvmmsg(rx, v.m, n, 0, NULL);
	MARK("burst-end");
	int order = got == (int)n;
	for (int i = 0; i < got && order; i++)
		order = v.f[i].can_id == ids[i];
	CHECK(sent == (int)n && order, "burst of %u: sent %d, received %d in order", n, sent, got);
}

int main(int argc, char **argv)
{
	if (argc < 3 || (strcmp(argv[1], "burst") == 0 && argc < 4)) {
		fprintf(stderr, "Usage: mmsg_probe checks <iface> | burst <iface> <n>\n");
		return 2;
	}
	alarm(PROBE_TIMEOUT_S);
	ifindex = (int)if_nametoindex(argv[2]);
	if (ifindex == 0) {
		perror(argv[2]);
		return 1;
	}
	if (strcmp(argv[1], "checks") == 0) {
		checks();
	} else if (strcmp(argv[1], "burst") == 0) {
		unsigned n = (unsigned)strtoul(argv[3], NULL, 10);
		if (n == 0 || n > VLEN_MAX) {
			fprintf(stderr, "mmsg_probe: burst of 1..%d frames\n", VLEN_MAX);
			return 2;
		}
		burst(n);
	} else {
		fprintf(stderr, "mmsg_probe: unknown mode %s\n", argv[1]);
		return 2;
	}
	return failures ? 1 : 0;
}
