/* floor_bridge.c - the least any immediate CAN -> Zenoh bridge does per frame,
 * without Zenoh: wait for a frame and read what is queued (one blocking
 * recvmmsg with MSG_WAITFORONE: the wakeup and the read in one syscall), then
 * write each frame to a TCP peer on loopback on its own (one send of 16 bytes,
 * TCP_NODELAY), as an immediate mode publishes each frame as it comes.
 * bench-bridge runs it beside zenoh-node and the Python reference on the same
 * load: its CPU per frame is the floor a target ratio is held against. The
 * peer is a child process that reads and discards (its CPU is not the
 * floor's, as the router's is not the bridge's).
 *
 * Two structures: one thread over all the buses (poll, then read each that is
 * ready: frames that arrive together on several buses cost one wakeup), or
 * with --thread-per-bus a thread per bus blocked in its own read, as
 * zenoh-node reads its buses (each bus's frame its own wakeup), all writing
 * to the one TCP connection.
 *
 * Usage: floor-bridge [--thread-per-bus] <iface[,iface...]> <count> <idle_ms>
 * Prints "ready" once its sockets are bound and the peer connected; exits
 * after count frames or idle_ms without one, printing {"frames": n,
 * "cpu_ns": ..., "switches": ...}: its CPU time (the kernel's run time of the
 * process, all its threads, getrusage) and context switches from "ready" to
 * its end.
 * Loopback only. */
#define _GNU_SOURCE
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <sys/wait.h>
#include <unistd.h>

#include "can_open.h"

#define MAX_IFACES 64
#define BURST 64

/* A TCP connection to a child that reads and discards until EOF. */
static int connect_sink(pid_t *child)
{
	int lfd = socket(AF_INET, SOCK_STREAM, 0);
	struct sockaddr_in addr = { .sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK) };
	socklen_t len = sizeof(addr);
	if (lfd < 0 || bind(lfd, (struct sockaddr *)&addr, sizeof(addr)) < 0 || listen(lfd, 1) < 0 ||
	    getsockname(lfd, (struct sockaddr *)&addr, &len) < 0) {
		perror("floor-bridge: sink");
		exit(1);
	}
	*child = fork();
	if (*child == 0) {
		int c = accept(lfd, NULL, NULL);
		char buf[65536];
		while (c >= 0 && read(c, buf, sizeof(buf)) > 0)
			;
		_exit(0);
	}
	close(lfd);
	int fd = socket(AF_INET, SOCK_STREAM, 0), one = 1;
	if (fd < 0 || connect(fd, (struct sockaddr *)&addr, sizeof(addr)) < 0) {
		perror("floor-bridge: connect");
		exit(1);
	}
	setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
	return fd;
}

/* Reads what one socket has queued (waiting for the first frame if wait) and writes each frame
 * to the link on its own: the frames read, 0 when the wait ended without one, -1 on a failed write. */
static int forward_burst(int fd, int wait, int link)
{
	struct can_frame frames[BURST];
	struct iovec iov[BURST];
	struct mmsghdr mm[BURST];
	for (int i = 0; i < BURST; i++) {
		iov[i] = (struct iovec){ .iov_base = &frames[i], .iov_len = sizeof(frames[i]) };
		mm[i] = (struct mmsghdr){ .msg_hdr = { .msg_iov = &iov[i], .msg_iovlen = 1 } };
	}
	int r = recvmmsg(fd, mm, BURST, wait ? MSG_WAITFORONE : MSG_DONTWAIT, NULL);
	for (int i = 0; i < r; i++)
		if (send(link, &frames[i], sizeof(frames[i]), 0) != sizeof(frames[i])) {
			perror("floor-bridge: send");
			return -1;
		}
	return r > 0 ? r : 0;
}

/* A bus's thread (--thread-per-bus): blocks in its socket's read (SO_RCVTIMEO: idle_ms) until
 * all the buses together forwarded count frames, or its bus fell idle. */
struct bus_reader {
	int fd, link;
	long count;
	atomic_long *got;
	int failed;
};

static void *read_bus(void *arg)
{
	struct bus_reader *b = arg;
	while (atomic_load(b->got) < b->count) {
		int r = forward_burst(b->fd, 1, b->link);
		if (r <= 0) {
			b->failed = r < 0;
			break;
		}
		atomic_fetch_add(b->got, r);
	}
	return NULL;
}

static long thread_per_bus(const int *fds, int n, int link, long count, int *failed)
{
	pthread_t threads[MAX_IFACES];
	struct bus_reader readers[MAX_IFACES];
	atomic_long got = 0;
	for (int k = 0; k < n; k++) {
		readers[k] = (struct bus_reader){ .fd = fds[k], .link = link, .count = count, .got = &got };
		if (pthread_create(&threads[k], NULL, read_bus, &readers[k]) != 0) {
			perror("floor-bridge: thread");
			exit(1);
		}
	}
	for (int k = 0; k < n; k++) {
		pthread_join(threads[k], NULL);
		*failed |= readers[k].failed;
	}
	return atomic_load(&got);
}

/* One thread: blocks in the read of a single bus; polls several, then reads each that is ready. */
static long one_thread(const int *fds, int n, int link, long count, long idle_ms, int *failed)
{
	struct pollfd pfds[MAX_IFACES];
	for (int i = 0; i < n; i++)
		pfds[i] = (struct pollfd){ .fd = fds[i], .events = POLLIN };
	long got = 0;
	while (got < count) {
		if (n > 1 && poll(pfds, (nfds_t)n, (int)idle_ms) < 1)
			break;
		int read_any = 0;
		for (int k = 0; k < n; k++) {
			if (n > 1 && !(pfds[k].revents & POLLIN))
				continue;
			int r = forward_burst(fds[k], n == 1, link);
			if (r < 0) {
				*failed = 1;
				return got;
			}
			got += r;
			read_any |= r > 0;
		}
		if (n == 1 && !read_any)
			break; /* SO_RCVTIMEO: idle */
	}
	return got;
}

static struct rusage usage(void)
{
	struct rusage ru;
	getrusage(RUSAGE_SELF, &ru);
	return ru;
}

static int64_t cpu_ns(const struct rusage *ru)
{
	return ((int64_t)ru->ru_utime.tv_sec + ru->ru_stime.tv_sec) * 1000000000 +
	       ((int64_t)ru->ru_utime.tv_usec + ru->ru_stime.tv_usec) * 1000;
}

int main(int argc, char **argv)
{
	int per_bus = argc > 1 && strcmp(argv[1], "--thread-per-bus") == 0;
	argc -= per_bus;
	argv += per_bus;
	if (argc != 4) {
		fprintf(stderr, "Usage: floor-bridge [--thread-per-bus] <iface[,iface...]> <count> <idle_ms>\n");
		return 2;
	}
	/* an idle bound of 0 (or none) would wait for ever on a bus that stopped: refused, as can-load does */
	char *end_count, *end_idle;
	long count = strtol(argv[2], &end_count, 10), idle_ms = strtol(argv[3], &end_idle, 10);
	if (*end_count || count < 1 || *end_idle || idle_ms < 1 || idle_ms > 600000) {
		fprintf(stderr, "floor-bridge: count must be >= 1 and idle_ms 1-600000 (got %s, %s)\n", argv[2], argv[3]);
		return 2;
	}
	int fds[MAX_IFACES], n = 0;
	for (char *save = NULL, *name = strtok_r(argv[1], ",", &save); name; name = strtok_r(NULL, ",", &save)) {
		if (n == MAX_IFACES) {
			fprintf(stderr, "floor-bridge: at most %d interfaces\n", MAX_IFACES);
			return 2;
		}
		fds[n++] = open_can("floor-bridge", name);
	}
	pid_t child;
	int link = connect_sink(&child);
	/* a socket read blocking (one bus, or a thread per bus): SO_RCVTIMEO bounds its wait */
	struct timeval idle = { .tv_sec = idle_ms / 1000, .tv_usec = (idle_ms % 1000) * 1000 };
	for (int k = 0; k < n; k++)
		setsockopt(fds[k], SOL_SOCKET, SO_RCVTIMEO, &idle, sizeof(idle));
	printf("ready\n");
	fflush(stdout);
	struct rusage start = usage();
	int failed = 0;
	long got = per_bus ? thread_per_bus(fds, n, link, count, &failed) : one_thread(fds, n, link, count, idle_ms, &failed);
	struct rusage last = usage(); /* an idle wait that ended the run sleeps: no CPU but its wakeup */
	close(link);
	waitpid(child, NULL, 0);
	if (failed)
		return 1;
	printf("{\"frames\": %ld, \"cpu_ns\": %lld, \"switches\": %ld}\n", got,
	       (long long)(cpu_ns(&last) - cpu_ns(&start)),
	       (last.ru_nvcsw + last.ru_nivcsw) - (start.ru_nvcsw + start.ru_nivcsw));
	return 0;
}
