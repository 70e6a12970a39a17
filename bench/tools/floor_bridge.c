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
 * Usage: floor-bridge <iface[,iface...]> <count> <idle_ms>
 * Prints "ready" once its sockets are bound and the peer connected; exits
 * after count frames or idle_ms without one, printing {"frames": n,
 * "cpu_ns": ..., "switches": ...}: its CPU time (the kernel's run time of the
 * process, getrusage) and context switches from "ready" to its end.
 * Loopback only. */
#define _GNU_SOURCE
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
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

int main(int argc, char **argv)
{
	if (argc != 4) {
		fprintf(stderr, "Usage: floor-bridge <iface[,iface...]> <count> <idle_ms>\n");
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
	/* one socket: block in recvmmsg itself (SO_RCVTIMEO bounds the wait); several: poll them */
	struct timeval idle = { .tv_sec = idle_ms / 1000, .tv_usec = (idle_ms % 1000) * 1000 };
	setsockopt(fds[0], SOL_SOCKET, SO_RCVTIMEO, &idle, sizeof(idle));
	struct pollfd pfds[MAX_IFACES];
	for (int i = 0; i < n; i++)
		pfds[i] = (struct pollfd){ .fd = fds[i], .events = POLLIN };
	printf("ready\n");
	fflush(stdout);
	struct rusage start = usage();

	struct can_frame frames[BURST];
	struct iovec iov[BURST];
	struct mmsghdr mm[BURST];
	long got = 0;
	while (got < count) {
		if (n > 1 && poll(pfds, (nfds_t)n, (int)idle_ms) < 1)
			break;
		int read_any = 0;
		for (int k = 0; k < n; k++) {
			if (n > 1 && !(pfds[k].revents & POLLIN))
				continue;
			for (int i = 0; i < BURST; i++) {
				iov[i] = (struct iovec){ .iov_base = &frames[i], .iov_len = sizeof(frames[i]) };
				mm[i] = (struct mmsghdr){ .msg_hdr = { .msg_iov = &iov[i], .msg_iovlen = 1 } };
			}
			int r = recvmmsg(fds[k], mm, BURST, n > 1 ? MSG_DONTWAIT : MSG_WAITFORONE, NULL);
			for (int i = 0; i < r; i++)
				if (send(link, &frames[i], sizeof(frames[i]), 0) != sizeof(frames[i])) {
					perror("floor-bridge: send");
					return 1;
				}
			if (r > 0) {
				got += r;
				read_any = 1;
			}
		}
		if (n == 1 && !read_any)
			break; /* SO_RCVTIMEO: idle */
	}
	struct rusage last = usage(); /* an idle wait that ended the run sleeps: no CPU but its wakeup */
	close(link);
	waitpid(child, NULL, 0);
	printf("{\"frames\": %ld, \"cpu_ns\": %lld, \"switches\": %ld}\n", got,
	       (long long)(cpu_ns(&last) - cpu_ns(&start)),
	       (last.ru_nvcsw + last.ru_nivcsw) - (start.ru_nvcsw + start.ru_nivcsw));
	return 0;
}
