/* preload_probe - a multithreaded SocketCAN program that does what the
 * preload library must survive (tests/bus/test_preload_probe.py drives it):
 *
 *   preload_probe fork <iface>     a thread queries an interface the hub does not have
 *                                  while the hub is stopped; fork; the child must not hang
 *   preload_probe unbound <iface>  poll, epoll and recv (SO_RCVTIMEO) before bind time out
 *                                  as on the kernel; then bind and receive one frame
 *   preload_probe stale <iface>    descriptors closed behind the library's back
 *                                  (fclose(fdopen()), the raw syscall) are not CAN any more
 *   preload_probe stamp <iface>    SIOCGSTAMP before any frame (ENOENT); read() + SIOCGSTAMP(NS)
 *                                  of a first frame, SCM_TIMESTAMPNS of a second (recvmsg with
 *                                  SO_TIMESTAMPNS); prints "stamp <sec>.<nsec>" per frame
 *   preload_probe exec <iface>     a socket gets a classic and an FD frame, then SO_TIMESTAMPNS,
 *                                  then two more, and is inherited across exec: the program
 *                                  exec'd reads all four (recvmmsg, then read() on a second one)
 *   preload_probe switch <iface>   a socket shared across fork: the parent turns stamps on and
 *                                  reads the first of four frames, the child the other three
 *
 * Prints one line per result; exit 0 when everything held, 1 otherwise. */
#define _GNU_SOURCE
#include <errno.h>
#include <net/if.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <sys/syscall.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>
#include <linux/can.h>
#include <linux/can/raw.h>
#include <linux/sockios.h>
#include <netinet/in.h>

#define UNBOUND_WAIT_MS 200
#define CHILD_DEADLINE_S 3

static int failures;

static void result(int ok, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void result(int ok, const char *fmt, ...)
{
	va_list ap;
	va_start(ap, fmt);
	printf("%s: ", ok ? "ok" : "FAIL");
	vprintf(fmt, ap);
	putchar('\n');
	fflush(stdout);
	va_end(ap);
	failures += !ok;
}

static double ms_since(const struct timespec *t0)
{
	struct timespec t;
	clock_gettime(CLOCK_MONOTONIC, &t);
	return (t.tv_sec - t0->tv_sec) * 1e3 + (t.tv_nsec - t0->tv_nsec) / 1e6;
}

static int can_socket(void)
{
	int s = socket(PF_CAN, SOCK_RAW, CAN_RAW);
	if (s < 0) {
		perror("preload_probe: socket");
		exit(1);
	}
	return s;
}

static void can_bind(int s, const char *iface)
{
	struct sockaddr_can addr = { .can_family = AF_CAN, .can_ifindex = (int)if_nametoindex(iface) };
	if (addr.can_ifindex == 0 || bind(s, (struct sockaddr *)&addr, sizeof(addr)) < 0) {
		fprintf(stderr, "preload_probe: bind %s: %s\n", iface, strerror(errno));
		exit(1);
	}
}

static void wait_line(const char *expected)
{
	char line[64];
	if (!fgets(line, sizeof(line), stdin) || strncmp(line, expected, strlen(expected)) != 0) {
		fprintf(stderr, "preload_probe: expected '%s' on stdin\n", expected);
		exit(1);
	}
}

/* ---- fork while another thread waits for the hub ---- */

static atomic_int querier_tid, stop_querying;

static void *query_missing(void *arg)
{
	(void)arg;
	querier_tid = (int)gettid();
	while (!stop_querying)
		if_nametoindex("nosuch0"); /* a miss asks the hub, at most once a second */
	return NULL;
}

/* The querier is blocked in poll(), waiting for the stopped hub's answer. */
static int querier_waiting(void)
{
	char path[64], buf[64];
	snprintf(path, sizeof(path), "/proc/self/task/%d/syscall", (int)querier_tid);
	FILE *f = fopen(path, "r");
	if (!f)
		return 0;
	int nr = -1;
	if (fgets(buf, sizeof(buf), f))
		nr = atoi(buf);
	fclose(f);
	return nr == SYS_poll || nr == SYS_ppoll;
}

static void probe_fork(const char *iface)
{
	unsigned index = if_nametoindex(iface);
	result(index != 0, "%s has index %u before the hub stops", iface, index);
	printf("ready\n");
	fflush(stdout);
	wait_line("stopped"); /* the driver stopped the hub */
	pthread_t t;
	pthread_create(&t, NULL, query_missing, NULL);
	struct timespec t0, tick = { 0, 1000000 };
	clock_gettime(CLOCK_MONOTONIC, &t0);
	while (!(querier_tid && querier_waiting()) && ms_since(&t0) < 5000)
		nanosleep(&tick, NULL); /* polling a readiness condition: the querier's syscall */
	result(querier_waiting(), "a thread waits for the stopped hub in poll()");
	pid_t child = fork();
	if (child == 0) {
		alarm(CHILD_DEADLINE_S);
		unsigned again = if_nametoindex(iface);
		int s = socket(PF_CAN, SOCK_RAW, CAN_RAW);
		close(s);
		_exit(again == index && s >= 0 ? 0 : 2);
	}
	int status;
	waitpid(child, &status, 0);
	result(WIFEXITED(status) && WEXITSTATUS(status) == 0, "the child looked up %s and opened a socket (%s)",
	       iface, WIFSIGNALED(status) ? "killed by its deadline: deadlocked" : "exited");
	printf("resume\n");
	fflush(stdout);
	stop_querying = 1;
	pthread_join(t, NULL);
}

/* ---- before bind ---- */

static void probe_unbound(const char *iface)
{
	int s = can_socket();
	struct pollfd pfd = { .fd = s, .events = POLLIN };
	struct timespec t0;
	clock_gettime(CLOCK_MONOTONIC, &t0);
	int rc = poll(&pfd, 1, UNBOUND_WAIT_MS);
	result(rc == 0, "poll before bind: %d (revents 0x%x) after %.0f ms", rc, rc > 0 ? pfd.revents : 0,
	       ms_since(&t0));

	int ep = epoll_create1(EPOLL_CLOEXEC);
	struct epoll_event ev = { .events = EPOLLIN }, out;
	epoll_ctl(ep, EPOLL_CTL_ADD, s, &ev);
	clock_gettime(CLOCK_MONOTONIC, &t0);
	rc = epoll_wait(ep, &out, 1, UNBOUND_WAIT_MS);
	result(rc == 0, "epoll before bind: %d (events 0x%x) after %.0f ms", rc, rc > 0 ? out.events : 0,
	       ms_since(&t0));
	close(ep);

	struct timeval tv = { 0, UNBOUND_WAIT_MS * 1000 };
	setsockopt(s, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
	struct can_frame f;
	alarm(5); /* blocking forever is the failure */
	clock_gettime(CLOCK_MONOTONIC, &t0);
	ssize_t n = recv(s, &f, sizeof(f), 0);
	int err = errno;
	double waited = ms_since(&t0);
	alarm(0);
	result(n < 0 && (err == EAGAIN || err == EWOULDBLOCK) && waited >= UNBOUND_WAIT_MS * 0.9,
	       "recv before bind with SO_RCVTIMEO: %zd (%s) after %.0f ms", n, n < 0 ? strerror(err) : "data",
	       waited);

	can_bind(s, iface);
	printf("ready\n");
	fflush(stdout);
	tv.tv_sec = 10;
	setsockopt(s, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
	n = read(s, &f, sizeof(f));
	result(n == (ssize_t)sizeof(f), "after bind: frame %03X", n == (ssize_t)sizeof(f) ? f.can_id : 0);
	close(s);
}

/* ---- descriptors closed behind the library's back ---- */

static void probe_stale(const char *iface)
{
	int s = can_socket();
	can_bind(s, iface);
	fclose(fdopen(s, "r+")); /* glibc closes without calling close() */
	int p[2];
	if (pipe(p) < 0 || (p[0] != s && p[1] != s)) {
		result(0, "the pipe did not reuse the closed socket's descriptor %d", s);
		return;
	}
	ssize_t w = write(p[1], "hello", 5);
	char buf[8] = "";
	ssize_t r = read(p[0], buf, sizeof(buf));
	result(w == 5 && r == 5 && memcmp(buf, "hello", 5) == 0,
	       "a pipe on descriptor %d after fclose(fdopen()): write %zd, read %zd", s, w, r);
	close(p[0]);
	close(p[1]);

	int s2 = can_socket();
	can_bind(s2, iface);
	syscall(SYS_close, s2);
	int u = socket(AF_INET, SOCK_DGRAM, 0);
	struct sockaddr_in sin = { .sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK) };
	socklen_t len = sizeof(sin);
	int bound = bind(u, (struct sockaddr *)&sin, sizeof(sin));
	int named = getsockname(u, (struct sockaddr *)&sin, &len);
	result(u == s2 && bound == 0 && named == 0 && sin.sin_family == AF_INET,
	       "a UDP socket on descriptor %d after the raw close: bind %d, getsockname family %d", u, bound,
	       sin.sin_family);
	close(u);
}

/* ---- the bus's stamp, as kernel CAN sockets give it ---- */

static void probe_stamp(const char *iface)
{
	int s = can_socket();
	can_bind(s, iface);
	struct timeval tv;
	int rc = ioctl(s, SIOCGSTAMP, &tv);
	result(rc < 0 && errno == ENOENT, "SIOCGSTAMP before any frame: %d (%s)", rc, rc < 0 ? strerror(errno) : "");
	printf("ready\n");
	fflush(stdout);
	struct can_frame f;
	ssize_t n = read(s, &f, sizeof(f));
	struct timespec ns;
	int a = ioctl(s, SIOCGSTAMP, &tv), b = ioctl(s, SIOCGSTAMPNS, &ns);
	result(n == (ssize_t)sizeof(f) && a == 0 && b == 0 && tv.tv_sec == ns.tv_sec && tv.tv_usec == ns.tv_nsec / 1000,
	       "read() then SIOCGSTAMP %ld.%06ld and SIOCGSTAMPNS %ld.%09ld", (long)tv.tv_sec, (long)tv.tv_usec,
	       (long)ns.tv_sec, ns.tv_nsec);
	printf("stamp %ld.%09ld\n", (long)ns.tv_sec, ns.tv_nsec);

	int on = 1;
	setsockopt(s, SOL_SOCKET, SO_TIMESTAMPNS, &on, sizeof(on));
	int got = 0;
	socklen_t len = sizeof(got);
	getsockopt(s, SOL_SOCKET, SO_TIMESTAMPNS, &got, &len);
	result(got == 1, "SO_TIMESTAMPNS reads back %d", got);
	printf("ready\n");
	fflush(stdout);
	char control[CMSG_SPACE(sizeof(struct timespec))];
	struct iovec iov = { &f, sizeof(f) };
	struct msghdr mh = { .msg_iov = &iov, .msg_iovlen = 1, .msg_control = control,
			     .msg_controllen = sizeof(control) };
	n = recvmsg(s, &mh, 0);
	struct timespec cm = { 0, 0 };
	int count = 0;
	for (struct cmsghdr *c = CMSG_FIRSTHDR(&mh); c; c = CMSG_NXTHDR(&mh, c), count++)
		if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SCM_TIMESTAMPNS)
			memcpy(&cm, CMSG_DATA(c), sizeof(cm));
	/* linux 6.1: a frame whose stamp went into a control message does not
	 * update the socket's SIOCGSTAMP stamp: it still names the first frame */
	struct timespec first = ns;
	b = ioctl(s, SIOCGSTAMPNS, &ns);
	int later = cm.tv_sec > first.tv_sec || (cm.tv_sec == first.tv_sec && cm.tv_nsec > first.tv_nsec);
	result(n == (ssize_t)sizeof(f) && count == 1 && later && b == 0 && ns.tv_sec == first.tv_sec &&
		       ns.tv_nsec == first.tv_nsec,
	       "recvmsg: %d control message(s), SCM_TIMESTAMPNS %ld.%09ld, SIOCGSTAMPNS still %ld.%09ld", count,
	       (long)cm.tv_sec, cm.tv_nsec, (long)ns.tv_sec, ns.tv_nsec);
	printf("stamp %ld.%09ld\n", (long)cm.tv_sec, cm.tv_nsec);
	close(s);
}

/* ---- a socket inherited across exec after its switch to stamps ---- */

#define EXEC_WAIT_MS 500

/* A classic frame and an FD frame, ids 0x101 + first and 0x102 + first, the payload bytes their index. */
static void send_pair(int tx, int first)
{
	struct can_frame f = { .can_id = 0x101 + first, .len = 1, .data = { (uint8_t)first } };
	struct canfd_frame fd = { .can_id = 0x102 + first, .len = 12 };
	memset(fd.data, first + 1, fd.len);
	if (write(tx, &f, sizeof(f)) != (ssize_t)sizeof(f) || write(tx, &fd, sizeof(fd)) != (ssize_t)sizeof(fd))
		result(0, "send 0x%03X and 0x%03X: %s", 0x101 + first, 0x102 + first, strerror(errno));
	/* an option set on a bound socket is applied before setsockopt returns (on the userspace
	 * bus a BARRIER, which reads the sender's frames first): both are in the reader's queue */
	int on = 1;
	setsockopt(tx, SOL_CAN_RAW, CAN_RAW_LOOPBACK, &on, sizeof(on));
}

static void probe_exec(const char *iface, const char *self)
{
	static const char *const modes[] = { "recvmmsg", "read" };
	for (unsigned m = 0; m < 2; m++) {
		int on = 1;
		int rx = can_socket(); /* inherited: no SOCK_CLOEXEC */
		setsockopt(rx, SOL_CAN_RAW, CAN_RAW_FD_FRAMES, &on, sizeof(on));
		can_bind(rx, iface);
		int tx = socket(PF_CAN, SOCK_RAW | SOCK_CLOEXEC, CAN_RAW);
		setsockopt(tx, SOL_CAN_RAW, CAN_RAW_FD_FRAMES, &on, sizeof(on));
		can_bind(tx, iface);
		send_pair(tx, 0); /* bare frames on the userspace bus: nothing asked for a header */
		setsockopt(rx, SOL_SOCKET, SO_TIMESTAMPNS, &on, sizeof(on)); /* the hub switches rx to headers */
		send_pair(tx, 2);
		close(tx);
		fflush(stdout);
		pid_t pid = fork();
		if (pid == 0) {
			char fd[16];
			snprintf(fd, sizeof(fd), "%d", rx);
			execl(self, self, "exec-child", fd, modes[m], (char *)NULL);
			_exit(127);
		}
		close(rx);
		int status = 0;
		waitpid(pid, &status, 0);
		result(WIFEXITED(status) && WEXITSTATUS(status) == 0, "%s after exec: the child read every frame (status %d)",
		       modes[m], status);
	}
}

/* Reads a socket until EXEC_WAIT_MS pass without a frame: send_pair's frames from index first to 3. */
static void read_pairs(int s, const char *mode, unsigned first)
{
	struct timeval tv = { 0, EXEC_WAIT_MS * 1000 };
	setsockopt(s, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
	struct canfd_frame got[8];
	unsigned size[8], n = 0;
	memset(got, 0, sizeof(got));
	while (n < 8) {
		if (strcmp(mode, "recvmmsg") == 0) {
			struct iovec iov[8];
			struct mmsghdr mm[8];
			for (unsigned i = 0; i < 8; i++) {
				iov[i] = (struct iovec){ &got[i], sizeof(got[i]) };
				mm[i] = (struct mmsghdr){ .msg_hdr = { .msg_iov = &iov[i], .msg_iovlen = 1 } };
			}
			int r = recvmmsg(s, mm + n, 8 - n, MSG_WAITFORONE, NULL);
			if (r <= 0)
				break;
			for (int i = 0; i < r; i++)
				size[n + i] = mm[n + i].msg_len;
			n += (unsigned)r;
		} else {
			ssize_t r = read(s, &got[n], sizeof(got[n]));
			if (r <= 0)
				break;
			size[n++] = (unsigned)r;
		}
	}
	int ok = n == 4 - first;
	for (unsigned k = 0; k < n; k++) {
		unsigned i = first + k;
		int fd = i % 2;
		uint8_t byte = (uint8_t)i, len = fd ? 12 : 1; /* as send_pair sent it */
		int good = got[k].can_id == 0x101 + i && size[k] == (fd ? CANFD_MTU : CAN_MTU) && got[k].len == len &&
			   got[k].data[0] == byte && got[k].data[len - 1] == byte;
		printf("%s: %s frame %u: id 0x%03X, %u bytes, len %u, data[0] %u\n", good ? "ok" : "FAIL", mode, i,
		       got[k].can_id, size[k], got[k].len, got[k].data[0]);
		ok &= good;
	}
	result(ok, "%s: %u frames from the shared socket (%u sent)", mode, n, 4 - first);
}

/* ---- a socket shared across fork, switched to stamps by the parent ---- */

/* The parent turns stamps on and reads the first frame, taking the hub's switch to headers
 * with it; the child forked before reads the other three: what one thread of a program sees
 * while another takes the switch (the library decodes by length, not by a mode it was told). */
static void probe_switch(const char *iface)
{
	static const char *const modes[] = { "recvmmsg", "read" };
	for (unsigned m = 0; m < 2; m++) {
		int on = 1, go[2];
		int rx = can_socket();
		setsockopt(rx, SOL_CAN_RAW, CAN_RAW_FD_FRAMES, &on, sizeof(on));
		can_bind(rx, iface);
		int tx = socket(PF_CAN, SOCK_RAW | SOCK_CLOEXEC, CAN_RAW);
		setsockopt(tx, SOL_CAN_RAW, CAN_RAW_FD_FRAMES, &on, sizeof(on));
		can_bind(tx, iface);
		if (pipe(go) < 0)
			result(0, "pipe: %s", strerror(errno));
		fflush(stdout);
		pid_t pid = fork();
		if (pid == 0) {
			char c;
			close(go[1]);
			if (read(go[0], &c, 1) == 1)
				read_pairs(rx, modes[m], 1);
			fflush(stdout);
			_exit(failures ? 1 : 0);
		}
		close(go[0]);
		setsockopt(rx, SOL_SOCKET, SO_TIMESTAMPNS, &on, sizeof(on)); /* the hub switches rx to headers */
		send_pair(tx, 0);
		send_pair(tx, 2);
		struct canfd_frame f;
		ssize_t n = read(rx, &f, sizeof(f));
		result(n == CAN_MTU && f.can_id == 0x101, "the parent read frame 0 behind the switch (%zd bytes, id 0x%03X)",
		       n, f.can_id);
		if (write(go[1], "g", 1) != 1)
			result(0, "pipe write: %s", strerror(errno));
		close(go[1]);
		close(tx);
		close(rx);
		int status = 0;
		waitpid(pid, &status, 0);
		result(WIFEXITED(status) && WEXITSTATUS(status) == 0, "%s in the child: every frame after the switch "
		       "(status %d)", modes[m], status);
	}
}

int main(int argc, char **argv)
{
	if (argc == 4 && strcmp(argv[1], "exec-child") == 0) {
		read_pairs(atoi(argv[2]), argv[3], 0);
		return failures ? 1 : 0;
	}
	if (argc != 3) {
		fprintf(stderr, "Usage: preload_probe fork|unbound|stale|stamp|exec|switch <iface>\n");
		return 2;
	}
	signal(SIGPIPE, SIG_IGN);
	if (strcmp(argv[1], "fork") == 0)
		probe_fork(argv[2]);
	else if (strcmp(argv[1], "unbound") == 0)
		probe_unbound(argv[2]);
	else if (strcmp(argv[1], "stale") == 0)
		probe_stale(argv[2]);
	else if (strcmp(argv[1], "stamp") == 0)
		probe_stamp(argv[2]);
	else if (strcmp(argv[1], "exec") == 0)
		probe_exec(argv[2], "/proc/self/exe");
	else if (strcmp(argv[1], "switch") == 0)
		probe_switch(argv[2]);
	else {
		fprintf(stderr, "preload_probe: unknown probe '%s'\n", argv[1]);
		return 2;
	}
	return failures ? 1 : 0;
}
