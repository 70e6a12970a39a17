/* fuzz_hub_state.c - libFuzzer harness for the hub's state (hub.c, in process):
 * an input is a program of rounds over up to MAX_CONNS real connections to
 * its listening socket. Each round, clients act while the hub waits (as if it
 * were stopped: whatever they do is handled in one loop round, in the order
 * it became readable), then the hub runs one loop round or catches up. Clients open and bind in
 * bulk (up to a full slot table), send frames and floods, BARRIERs naming
 * each other, queries, raw bytes, close, read or never read. The oracle:
 * ASan/UBSan, the hub's assertions, hub_check_invariants after each round
 * (queues within their bounds), and nothing leaked at the end.
 *
 * Code coverage alone does not tell a round that closes and reopens a slot
 * in a full table from one that does either alone: the shape of each round
 * (table full, frame sent, slot freed, slot taken, a BARRIER naming a
 * connection of this round) is fed back as libFuzzer extra counters, so
 * inputs reaching a new combination are kept and built on.
 *
 * Grammar (bytes; a missing byte reads as 0):
 *   input  := round*          round := count op{1 + count % 16}, then one
 *                             loop round (count bit 7) or until the hub is idle
 *   op     := kind arg...     connection arguments: bit 7 set = the newest
 *                             connection, else index % open connections
 *   kind % 11: 0 open 1+a%8 (b: bind flags)   1 fill the slot table (b)
 *              2 frame (c, id: bit 7 vcan1, len: bit 7 FD)
 *              3 barrier (c, target)           4 close (c)
 *              5 query (c, kind, target)       6 read (c, or all if a == 0)
 *              7 raw (c, len, bytes)           8 flood 8*(1+n%32) frames (c, n)
 *              9 setopt (c, bind flags)        10 reconnect: close c, open one (b)
 *   bind flags: bit 7 clear: a typical client (bound to vcan0, loopback,
 *               its own frames back); set: bit 0 unbound, 1 recv_own,
 *               2 loopback off, 3 timestamps, 4 any interface, 5 fd frames,
 *               6 vcan1 with rcvbuf 1 MiB */
#define _GNU_SOURCE
#include <errno.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include "hub.h"
#include "ucan_proto.h"

#define MAX_CONNS 200
#define SLOT_TABLE 64 /* the hub's client table grows by doubling from this */
#define MAX_CATCH_UP_ROUNDS 64

struct input {
	const uint8_t *data;
	size_t size, pos;
};

static uint8_t next(struct input *in)
{
	return in->pos < in->size ? in->data[in->pos++] : 0;
}

enum shape { TABLE_FULL = 1, FRAME_SENT = 2, SLOT_FREED = 4, SLOT_TAKEN = 8, BARRIER_TO_NEW = 16 };
__attribute__((used, section("__libfuzzer_extra_counters"))) static uint8_t round_shapes[32];

static struct {
	unsigned shape; /* enum shape bits of the round being written */
	unsigned round; /* rounds so far in this input */
	unsigned born[MAX_CONNS]; /* the round each connection was opened in */
	int fd[MAX_CONNS];
	unsigned n;
	unsigned serial; /* abstract names unique within an input */
	char dir[64];
} conns;

static int pick(struct input *in)
{
	uint8_t b = next(in);
	if (conns.n == 0)
		return -1;
	return b & 0x80 ? (int)conns.n - 1 : (int)(b % conns.n);
}

static void cookie_of(unsigned serial, char *out)
{
	/* abstract names are machine-wide: the pid keeps parallel fuzzers apart */
	snprintf(out, UCAN_COOKIE_MAX, "ucan/fz/%d/%u", (int)getpid(), serial);
}

static unsigned serial_of[MAX_CONNS];

static void send_msg(int c, const void *msg, size_t len)
{
	if (c >= 0) /* a full socket (the hub has not read) drops the message, like a sender giving up */
		(void)send(conns.fd[c], msg, len, MSG_DONTWAIT | MSG_NOSIGNAL);
}

static void send_opts(int c, uint32_t type, uint8_t flags)
{
	if (!(flags & 0x80))
		flags = 0x02; /* a typical client: bound to vcan0, loopback on, its own frames back */
	struct ucan_sockopts o = { .type = type, .ifindex = flags & 16 ? 0 : UCAN_IFINDEX_BASE + !!(flags & 64),
				   .rcvbuf = flags & 64 ? 1u << 20 : 0, .loopback = !(flags & 4),
				   .recv_own = !!(flags & 2), .fd_frames = !!(flags & 32), .nfilters = 1 };
	o.timestamps = flags & 8 ? UCAN_TS_NSEC : UCAN_TS_NONE;
	uint8_t msg[sizeof(o) + sizeof(struct can_filter)] = { 0 };
	memcpy(msg, &o, sizeof(o));
	send_msg(c, msg, sizeof(msg));
}

static void open_conn(uint8_t flags)
{
	if (conns.n >= MAX_CONNS)
		return;
	int fd = socket(AF_UNIX, SOCK_SEQPACKET | SOCK_CLOEXEC, 0);
	struct sockaddr_un addr = { .sun_family = AF_UNIX };
	char cookie[UCAN_COOKIE_MAX];
	cookie_of(conns.serial, cookie);
	memcpy(addr.sun_path + 1, cookie, strlen(cookie));
	socklen_t len = (socklen_t)(offsetof(struct sockaddr_un, sun_path) + 1 + strlen(cookie));
	struct sockaddr_un hub_addr = { .sun_family = AF_UNIX };
	snprintf(hub_addr.sun_path, sizeof(hub_addr.sun_path), "%s", hub_socket_path());
	if (fd < 0 || bind(fd, (struct sockaddr *)&addr, len) < 0 ||
	    connect(fd, (struct sockaddr *)&hub_addr, sizeof(hub_addr)) < 0) {
		perror("fuzz_hub_state: connect"); /* the harness itself failed: not a finding */
		abort();
	}
	serial_of[conns.n] = conns.serial++;
	conns.born[conns.n] = conns.round;
	conns.fd[conns.n++] = fd;
	conns.shape |= SLOT_TAKEN;
	if (!(flags & 0x80 && flags & 1))
		send_opts((int)conns.n - 1, UCAN_MSG_BIND, flags);
}

static void close_conn(int c)
{
	if (c < 0)
		return;
	close(conns.fd[c]);
	conns.shape |= SLOT_FREED;
	conns.n--;
	conns.fd[c] = conns.fd[conns.n];
	conns.born[c] = conns.born[conns.n];
	serial_of[c] = serial_of[conns.n];
}

static void read_conn(int c)
{
	uint8_t buf[8192];
	while (recv(conns.fd[c], buf, sizeof(buf), MSG_DONTWAIT) > 0)
		;
}

static void send_frame(int c, uint8_t id, uint8_t len)
{
	uint8_t msg[sizeof(struct ucan_txhdr) + CANFD_MTU] = { 0 };
	struct ucan_txhdr hdr = { .type = UCAN_MSG_FRAME, .ifindex = UCAN_IFINDEX_BASE + (id >> 7) };
	int fd_frame = len & 0x80; /* else classic: every reader takes it */
	struct canfd_frame f = { .can_id = id, .len = (uint8_t)(fd_frame ? len % 65 : len % 9) };
	memcpy(msg, &hdr, sizeof(hdr));
	memcpy(msg + sizeof(hdr), &f, sizeof(f));
	send_msg(c, msg, sizeof(hdr) + (fd_frame ? CANFD_MTU : CAN_MTU));
	if (c >= 0)
		conns.shape |= FRAME_SENT;
}

static void do_op(struct input *in)
{
	uint8_t kind = next(in) % 11;
	switch (kind) {
	case 0: {
		unsigned n = 1 + next(in) % 8;
		uint8_t flags = next(in);
		while (n--)
			open_conn(flags);
		break;
	}
	case 1: { /* every slot of the hub's table taken: where reuse and growth meet */
		uint8_t flags = next(in);
		unsigned target = (conns.n / SLOT_TABLE + 1) * SLOT_TABLE;
		while (conns.n < target && conns.n < MAX_CONNS)
			open_conn(flags);
		break;
	}
	case 2: {
		int c = pick(in);
		uint8_t id = next(in), len = next(in);
		send_frame(c, id, len);
		break;
	}
	case 3: {
		int c = pick(in), t = pick(in);
		struct ucan_barrier b = { .type = UCAN_MSG_BARRIER };
		if (t >= 0)
			cookie_of(serial_of[t], b.cookie);
		send_msg(c, &b, sizeof(b));
		if (c >= 0 && t >= 0 && conns.born[t] == conns.round)
			conns.shape |= BARRIER_TO_NEW;
		break;
	}
	case 4:
		close_conn(pick(in));
		break;
	case 5: {
		int c = pick(in);
		static const uint32_t kinds[] = { UCAN_MSG_STATS, UCAN_MSG_IFLIST, UCAN_MSG_RESET_STATS, UCAN_MSG_GETOPT };
		uint32_t k = kinds[next(in) % 4];
		int t = pick(in);
		struct ucan_barrier q = { .type = k };
		if (t >= 0)
			cookie_of(serial_of[t], q.cookie);
		send_msg(c, &q, k == UCAN_MSG_GETOPT ? sizeof(q) : sizeof(k));
		break;
	}
	case 6: {
		uint8_t a = next(in);
		for (unsigned c = 0; c < conns.n; c++)
			if (a == 0 || c == a % conns.n)
				read_conn((int)c);
		break;
	}
	case 7: {
		int c = pick(in);
		uint8_t msg[256];
		size_t len = next(in);
		for (size_t i = 0; i < len; i++)
			msg[i] = next(in);
		send_msg(c, msg, len);
		break;
	}
	case 8: {
		int c = pick(in);
		unsigned n = 8 * (1 + next(in) % 32);
		for (unsigned i = 0; i < n; i++)
			send_frame(c, (uint8_t)i, 8);
		break;
	}
	case 9: {
		int c = pick(in);
		send_opts(c, UCAN_MSG_SETOPT, next(in));
		break;
	}
	case 10: { /* a program restarting: its slot is free for whoever connects next */
		int c = pick(in);
		uint8_t flags = next(in);
		if (c >= 0) {
			close_conn(c);
			open_conn(flags);
		}
		break;
	}
	}
}

int LLVMFuzzerInitialize(int *argc, char ***argv)
{
	(void)argc;
	(void)argv;
	snprintf(conns.dir, sizeof(conns.dir), "/tmp/ucan-fuzz-XXXXXX");
	if (!mkdtemp(conns.dir)) {
		perror("fuzz_hub_state: mkdtemp");
		abort();
	}
	return 0;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
	struct input in = { data, size, 0 };
	struct hub_options opts = { .dir = conns.dir, .default_queue = 64, .verbose = -1 };
	if (hub_add_iface("vcan0") < 0 || hub_add_iface("vcan1:mtu=16") < 0 || hub_start(&opts) < 0)
		abort();
	while (in.pos < in.size) {
		uint8_t count = next(&in);
		conns.shape = conns.n && conns.n % SLOT_TABLE == 0 ? TABLE_FULL : 0;
		conns.round++;
		for (unsigned ops = 1 + count % 16; ops; ops--)
			do_op(&in);
		round_shapes[conns.shape]++;
		/* bit 7: one loop round, else the hub catches up (until a round finds nothing) */
		for (unsigned round = 0; round < (count & 0x80 ? 1u : MAX_CATCH_UP_ROUNDS); round++) {
			int events = hub_run_once(0);
			if (events < 0)
				abort();
			hub_check_invariants();
			if (events == 0)
				break;
		}
	}
	while (conns.n)
		close_conn(0);
	hub_run_once(0);
	hub_check_invariants();
	hub_shutdown();
	conns.serial = conns.round = 0;
	return 0;
}
