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
 * Usage: floor-bridge [-t|--thread-per-bus] <iface[,iface...]> <count> <idle_ms>
 * Prints "ready" once its sockets are bound and the peer connected; exits
 * after count frames or idle_ms without one, printing {"frames": n,
 * "cpu_ns": ..., "switches": ...}: its CPU time (the kernel's run time of the
 * process, all its threads, getrusage) and context switches from "ready" to
 * its last frame (or the idle wait that ended the run).
 * Loopback only. */
#define _GNU_SOURCE
#include <getopt.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
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
		if (send(link, &frames[i], sizeof(frames[i]), MSG_NOSIGNAL) != sizeof(frames[i])) {
			perror("floor-bridge: send");
			return -1;
		}
	return r > 0 ? r : 0;
}

/* --thread-per-bus: the readers share what they forwarded; the main thread sleeps until all of
 * it is in (or every reader ended: a bus idle for idle_ms) and takes the CPU figure then. The
 * readers still blocked in a read at that point end with the process (hence file scope). */
static struct shared {
	pthread_mutex_t lock;
	pthread_cond_t ended;
	long got, count;
	int live, failed;
} shared = { .lock = PTHREAD_MUTEX_INITIALIZER, .ended = PTHREAD_COND_INITIALIZER };

static struct bus_reader {
	int fd, link;
} readers[MAX_IFACES];

/* A bus's thread: blocks in its socket's read (SO_RCVTIMEO: idle_ms) as zenoh-node's reader
 * does, until the buses together forwarded count frames or its bus fell idle. */
static void *read_bus(void *arg)
{
	const struct bus_reader *b = arg;
	for (int ended = 0; !ended;) {
		int r = forward_burst(b->fd, 1, b->link);
		pthread_mutex_lock(&shared.lock);
		shared.got += r > 0 ? r : 0;
		shared.failed |= r < 0;
		ended = r <= 0 || shared.got >= shared.count;
		if (ended) {
			shared.live--;
			pthread_cond_signal(&shared.ended);
		}
		pthread_mutex_unlock(&shared.lock);
	}
	return NULL;
}

/* Returns the frames forwarded, *at the CPU figure taken as the last came in (or the last reader
 * ended). */
static long thread_per_bus(const int *fds, int n, int link, long count, int *failed, struct rusage *at)
{
	shared.count = count;
	shared.live = n;
	for (int k = 0; k < n; k++) {
		readers[k] = (struct bus_reader){ .fd = fds[k], .link = link };
		pthread_t thread;
		if (pthread_create(&thread, NULL, read_bus, &readers[k]) != 0) {
			perror("floor-bridge: thread");
			exit(1);
		}
		pthread_detach(thread);
	}
	pthread_mutex_lock(&shared.lock);
	while (shared.got < count && shared.live > 0)
		pthread_cond_wait(&shared.ended, &shared.lock);
	*at = usage();
	*failed = shared.failed;
	long got = shared.got;
	pthread_mutex_unlock(&shared.lock);
	return got;
}

/* One thread over all the buses: frames that arrive together on several buses cost one wakeup
 * (the poll), where zenoh-node's thread per bus wakes for each. A single bus needs no poll: the
 * read itself waits. */
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

static int usage_error(void)
{
	fprintf(stderr, "Usage: floor-bridge [-t|--thread-per-bus] <iface[,iface...]> <count> <idle_ms>\n");
	return 2;
}

int main(int argc, char **argv)
{
	static const struct option options[] = { { "thread-per-bus", no_argument, NULL, 't' }, { 0 } };
	int per_bus = 0;
	for (int c; (c = getopt_long(argc, argv, "t", options, NULL)) != -1;) {
		if (c != 't')
			return usage_error();
		per_bus = 1;
	}
	if (argc - optind != 3)
		return usage_error();
	char *ifaces = argv[optind], *count_arg = argv[optind + 1], *idle_arg = argv[optind + 2];
	/* an idle bound of 0 (or none) would wait for ever on a bus that stopped: refused, as can-load does */
	char *end_count, *end_idle;
	long count = strtol(count_arg, &end_count, 10), idle_ms = strtol(idle_arg, &end_idle, 10);
	if (*end_count || count < 1 || *end_idle || idle_ms < 1 || idle_ms > 600000) {
		fprintf(stderr, "floor-bridge: count must be >= 1 and idle_ms 1-600000 (got %s, %s)\n", count_arg, idle_arg);
		return 2;
	}
	int fds[MAX_IFACES], n = 0;
	for (char *save = NULL, *name = strtok_r(ifaces, ",", &save); name; name = strtok_r(NULL, ",", &save)) {
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
	struct rusage start = usage(), last;
	int failed = 0;
	long got;
	if (per_bus) {
		got = thread_per_bus(fds, n, link, count, &failed, &last);
	} else {
		got = one_thread(fds, n, link, count, idle_ms, &failed);
		last = usage(); /* an idle wait that ended the run sleeps: no CPU but its wakeup */
	}
	close(link);
	waitpid(child, NULL, 0);
	if (failed)
		return 1;
	printf("{\"frames\": %ld, \"cpu_ns\": %lld, \"switches\": %ld}\n", got,
	       (long long)(cpu_ns(&last) - cpu_ns(&start)),
	       (last.ru_nvcsw + last.ru_nivcsw) - (start.ru_nvcsw + start.ru_nivcsw));
	return 0;
}
