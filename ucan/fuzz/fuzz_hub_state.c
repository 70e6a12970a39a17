/* fuzz_hub_state.c - libFuzzer harness for the hub's state (hub.c, in process):
 * an input is a program over up to MAX_CONNS real connections to its listening
 * socket. The hub is paused while clients act (as if stopped: whatever they do
 * is handled in its next loop round, in the order it became readable) until an
 * op lets it run one loop round or catch up. Clients open and bind in bulk (up
 * to a full slot table), send frames and floods, BARRIERs naming each other,
 * queries, raw bytes, close, reconnect, read or never read. The oracle:
 * ASan/UBSan, the hub's assertions, hub_check_invariants after each round
 * (queues within their bounds), and nothing leaked at the end.
 *
 * The encoding is dense: one byte is one op (kind = low 3 bits, operand a =
 * high 5 bits), so a short input is a meaningful program and a mutation of
 * one byte is a change of one op. Code coverage alone does not tell a round
 * that closes and reopens a slot in a full table from one that does either
 * alone, nor in which order: the shape of each round (table full, frame sent,
 * slot freed, slot taken, a BARRIER naming a connection of this round) and
 * each pair of consecutive op kinds in it (split by table full or not) are
 * fed back as libFuzzer extra counters, so inputs reaching a new combination
 * are kept and built on.
 *
 * Grammar (bytes; a missing byte reads as 0). Clients: c(v) = the newest
 * connection if v == 15, else connection v % open connections (v < 16).
 *   kind 0 open 1 + a%4 clients with bind profile a/4 (0 typical)
 *        1 bind all: open clients until the slot table is full (typical if
 *          a < 16, else profile a%8), then the hub catches up
 *        2 frame from c(a%16), classic on vcan0 (a & 16: 64-byte FD frame)
 *        3 barrier from c(a%16) naming the newest connection (a & 16: naming
 *          c(next byte))
 *        4 close c(a%16) (a & 16: and read every other client)
 *        5 reconnect: close c(a%16), open one typical client (a & 16: one
 *          that only connects)
 *        6 the hub runs one loop round (a < 16) or catches up (until idle)
 *        7 more, by a%8, with following bytes (x, y):
 *          0 query kind a/8 (STATS IFLIST RESET_STATS GETOPT) from c(x) about c(y)
 *          1 read c(x) (a/8 == 0: every client)     2 flood 8*(1+y%32) frames from c(x)
 *            (a/8 odd: in UCAN_MSG_FRAMES batches of up to 64, both interfaces, some FD)
 *          3 setopt c(x), bind flags y               4 raw: c(x), length y, y bytes
 *          5 open 1+a/8 clients with bind flags x    6 frame from c(x): id y, len byte z
 *          7 barrier from c(x) naming c(y)
 *   profiles 0-7: typical (bound to vcan0, loopback, its own frames back),
 *   unbound, no own frames, loopback off, timestamps, any interface, FD
 *   frames, vcan1 with rcvbuf 1 MiB
 *   bind flags: bit 7 clear: typical; set: bit 0 unbound, 1 recv_own,
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
/* per round: its shape, and each pair of consecutive op kinds (table full at the round's start or not) */
__attribute__((used, section("__libfuzzer_extra_counters"))) static uint8_t round_shapes[32 + 2 * 8 * 8];

static struct {
	unsigned shape; /* enum shape bits of the round being written */
	int last_kind;	/* the previous op kind in this round, -1 at its start */
	unsigned full_at_start; /* the slot table was full when the round began */
	unsigned round; /* rounds so far in this input */
	unsigned born[MAX_CONNS]; /* the round each connection was opened in */
	int fd[MAX_CONNS];
	unsigned n;
	unsigned serial; /* abstract names unique within an input */
	char dir[64];
} conns;

/* c(v): the newest connection if v == 15, else connection v % open connections; -1 if none */
static int conn_of(unsigned v)
{
	if (conns.n == 0)
		return -1;
	return v % 16 == 15 ? (int)conns.n - 1 : (int)(v % 16 % conns.n);
}

static const uint8_t profiles[8] = { 0x02, 0x81, 0x80, 0x84, 0x8a, 0x92, 0xa2, 0xc2 };

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
#ifdef UCAN_TS_MAX /* (a hub from before timestamps has no such field) */
	o.timestamps = flags & 8 ? UCAN_TS_NSEC : UCAN_TS_NONE;
#endif
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

/* n frames in batches of up to 64: ids 0..n-1, the interface by id as send_frame,
 * every 16th an FD frame */
static void send_batches(int c, unsigned n)
{
	static uint8_t msg[sizeof(struct ucan_txbatch) + 64 * (sizeof(struct ucan_txrec) + CANFD_MTU)];
	for (unsigned first = 0; first < n; first += 64) {
		unsigned count = n - first < 64 ? n - first : 64;
		struct ucan_txbatch head = { .type = UCAN_MSG_FRAMES, .count = count };
		size_t at = sizeof(head);
		memcpy(msg, &head, sizeof(head));
		for (unsigned i = first; i < first + count; i++) {
			uint8_t id = (uint8_t)i;
			int fd_frame = i % 16 == 15 && id < 128; /* vcan1 is classic */
			struct canfd_frame f = { .can_id = id, .len = fd_frame ? 64 : 8 };
			struct ucan_txrec rec = { .ifindex = UCAN_IFINDEX_BASE + (id >> 7), .size = fd_frame ? CANFD_MTU : CAN_MTU };
			memcpy(msg + at, &rec, sizeof(rec));
			memcpy(msg + at + sizeof(rec), &f, rec.size);
			at += sizeof(rec) + rec.size;
		}
		send_msg(c, msg, at);
	}
	if (c >= 0)
		conns.shape |= FRAME_SENT;
}

static void send_barrier(int c, int t)
{
	struct ucan_barrier b = { .type = UCAN_MSG_BARRIER };
	if (t >= 0)
		cookie_of(serial_of[t], b.cookie);
	send_msg(c, &b, sizeof(b));
	if (c >= 0 && t >= 0 && conns.born[t] == conns.round)
		conns.shape |= BARRIER_TO_NEW;
}

static void begin_round(void)
{
	conns.full_at_start = conns.n && conns.n % SLOT_TABLE == 0;
	conns.shape = conns.full_at_start ? TABLE_FULL : 0;
	conns.last_kind = -1;
	conns.round++;
}

/* the hub runs one loop round (once) or until a round finds nothing */
static void run_hub(int once)
{
	round_shapes[conns.shape]++;
	for (unsigned round = 0; round < (once ? 1u : MAX_CATCH_UP_ROUNDS); round++) {
		int events = hub_run_once(0);
		if (events < 0)
			abort();
#ifndef FUZZ_HUB_NO_INVARIANTS /* a hub from before hub_check_invariants (proving the harness on old code) */
		hub_check_invariants();
#endif
		if (events == 0)
			break;
	}
	begin_round();
}

static void do_more(struct input *in, unsigned a)
{
	unsigned arg = a / 8;
	switch (a % 8) {
	case 0: {
		static const uint32_t kinds[] = { UCAN_MSG_STATS, UCAN_MSG_IFLIST, UCAN_MSG_RESET_STATS, UCAN_MSG_GETOPT };
		int c = conn_of(next(in)), t = conn_of(next(in));
		struct ucan_barrier q = { .type = kinds[arg] };
		if (t >= 0)
			cookie_of(serial_of[t], q.cookie);
		send_msg(c, &q, q.type == UCAN_MSG_GETOPT ? sizeof(q) : sizeof(q.type));
		break;
	}
	case 1: {
		int c = conn_of(next(in));
		for (unsigned i = 0; i < conns.n; i++)
			if (arg == 0 || (int)i == c)
				read_conn((int)i);
		break;
	}
	case 2: {
		int c = conn_of(next(in));
		unsigned n = 8 * (1 + next(in) % 32);
		if (arg & 1)
			send_batches(c, n);
		else
			for (unsigned i = 0; i < n; i++)
				send_frame(c, (uint8_t)i, 8);
		break;
	}
	case 3: {
		int c = conn_of(next(in));
		send_opts(c, UCAN_MSG_SETOPT, next(in));
		break;
	}
	case 4: {
		int c = conn_of(next(in));
		uint8_t msg[256];
		size_t len = next(in);
		for (size_t i = 0; i < len; i++)
			msg[i] = next(in);
		send_msg(c, msg, len);
		break;
	}
	case 5: {
		uint8_t flags = next(in);
		for (unsigned i = 0; i <= arg; i++)
			open_conn(flags);
		break;
	}
	case 6: {
		int c = conn_of(next(in));
		uint8_t id = next(in), len = next(in);
		send_frame(c, id, len);
		break;
	}
	case 7: {
		int c = conn_of(next(in));
		send_barrier(c, conn_of(next(in)));
		break;
	}
	}
}

static void do_op(struct input *in)
{
	uint8_t op = next(in);
	unsigned kind = op % 8, a = op / 8;
	if (conns.last_kind >= 0)
		round_shapes[32 + conns.full_at_start * 64 + conns.last_kind * 8 + kind]++;
	conns.last_kind = (int)kind;
	switch (kind) {
	case 0:
		for (unsigned n = 1 + a % 4; n; n--)
			open_conn(profiles[a / 4]);
		break;
	case 1: { /* every slot of the hub's table taken and bound: where reuse and growth meet */
		unsigned target = (conns.n / SLOT_TABLE + 1) * SLOT_TABLE;
		while (conns.n < target && conns.n < MAX_CONNS)
			open_conn(a < 16 ? profiles[0] : profiles[a % 8]);
		run_hub(0);
		break;
	}
	case 2: {
		int c = conn_of(a);
		send_frame(c, (uint8_t)(conns.round & 0x7f), a & 16 ? 0x80 | 64 : 8);
		break;
	}
	case 3: {
		int c = conn_of(a);
		send_barrier(c, a & 16 ? conn_of(next(in)) : (int)conns.n - 1);
		break;
	}
	case 4: {
		int c = conn_of(a);
		close_conn(c);
		if (a & 16)
			for (unsigned i = 0; i < conns.n; i++)
				read_conn((int)i);
		break;
	}
	case 5: { /* a program restarting: its slot is free for whoever connects next */
		int c = conn_of(a);
		if (c >= 0) {
			close_conn(c);
			open_conn(a & 16 ? profiles[1] : profiles[0]);
		}
		break;
	}
	case 6:
		run_hub(a < 16);
		break;
	case 7:
		do_more(in, a);
		break;
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
	begin_round();
	while (in.pos < in.size)
		do_op(&in);
	run_hub(0);
	while (conns.n)
		close_conn(0);
	hub_run_once(0);
#ifndef FUZZ_HUB_NO_INVARIANTS
	hub_check_invariants();
#endif
	hub_shutdown();
	conns.serial = conns.round = 0;
	return 0;
}
