/* hop_latency - one-hop latency of a CAN bus: a sender thread writes frames
 * carrying their send time (CLOCK_REALTIME ns); the reader takes the receive
 * timestamp the kernel put on the socket (SO_TIMESTAMPNS). Mode "socketpair"
 * measures the same over a plain unix socketpair: the floor any userspace bus
 * starts from, measured in the same run as the baseline.
 *
 * Usage: hop_latency can <iface> <count> <frames_per_s>
 *        hop_latency socketpair - <count> <frames_per_s>
 * Prints one JSON object: count, received, p50/p90/p99/max in microseconds. */
#define _GNU_SOURCE
#include <errno.h>
#include <poll.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>
#include <linux/can.h>
#include <linux/can/raw.h>

#include "can_open.h"

#define RECV_TIMEOUT_MS 2000

static int tx_fd, rx_fd;
static long count, rate;

static int64_t now_ns(clockid_t clock)
{
	struct timespec ts;
	clock_gettime(clock, &ts);
	return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

static void *sender(void *arg)
{
	(void)arg;
	int64_t start = now_ns(CLOCK_MONOTONIC), gap = 1000000000 / rate;
	for (long i = 0; i < count; i++) {
		/* sleep to each send time: a busy-waiting sender would steal the CPU the bus needs */
		int64_t due = start + i * gap;
		struct timespec ts = { .tv_sec = due / 1000000000, .tv_nsec = due % 1000000000 };
		while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR)
			;
		struct can_frame f = { .can_id = 0x123, .len = 8 };
		int64_t t = now_ns(CLOCK_REALTIME);
		memcpy(f.data, &t, sizeof(t));
		if (write(tx_fd, &f, sizeof(f)) != sizeof(f)) {
			perror("write");
			exit(1);
		}
	}
	return NULL;
}

static int cmp(const void *a, const void *b)
{
	int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
	return (x > y) - (x < y);
}

int main(int argc, char **argv)
{
	if (argc != 5) {
		fprintf(stderr, "Usage: hop_latency can|socketpair <iface> <count> <frames_per_s>\n");
		return 2;
	}
	count = strtol(argv[3], NULL, 10);
	rate = strtol(argv[4], NULL, 10);
	if (count <= 0 || rate <= 0)
		return 2;
	if (strcmp(argv[1], "socketpair") == 0) {
		int sv[2];
		if (socketpair(AF_UNIX, SOCK_SEQPACKET, 0, sv) < 0) {
			perror("socketpair");
			return 1;
		}
		tx_fd = sv[0];
		rx_fd = sv[1];
	} else {
		rx_fd = open_can("hop_latency", argv[2]);
		tx_fd = open_can("hop_latency", argv[2]);
	}
	int on = 1, rcvbuf = 8 << 20;
	setsockopt(rx_fd, SOL_SOCKET, SO_TIMESTAMPNS, &on, sizeof(on));
	setsockopt(rx_fd, SOL_SOCKET, SO_RCVBUF, &rcvbuf, sizeof(rcvbuf));
	int64_t *lat = calloc((size_t)count, sizeof(*lat));
	pthread_t tid;
	pthread_create(&tid, NULL, sender, NULL);
	long got = 0;
	while (got < count) {
		struct pollfd pfd = { .fd = rx_fd, .events = POLLIN };
		if (poll(&pfd, 1, RECV_TIMEOUT_MS) != 1)
			break;
		struct can_frame f;
		char control[CMSG_SPACE(sizeof(struct timespec))];
		struct iovec iov = { .iov_base = &f, .iov_len = sizeof(f) };
		struct msghdr mh = { .msg_iov = &iov, .msg_iovlen = 1, .msg_control = control,
				     .msg_controllen = sizeof(control) };
		if (recvmsg(rx_fd, &mh, 0) != sizeof(f))
			continue;
		int64_t sent, stamped = now_ns(CLOCK_REALTIME);
		memcpy(&sent, f.data, sizeof(sent));
		for (struct cmsghdr *c = CMSG_FIRSTHDR(&mh); c; c = CMSG_NXTHDR(&mh, c))
			if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SO_TIMESTAMPNS) {
				struct timespec ts;
				memcpy(&ts, CMSG_DATA(c), sizeof(ts));
				stamped = (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
			}
		lat[got++] = stamped - sent;
	}
	pthread_join(tid, NULL);
	qsort(lat, (size_t)got, sizeof(*lat), cmp);
#define PCT(p) (got ? lat[(long)((got - 1) * (p))] / 1000.0 : -1.0)
	printf("{\"count\": %ld, \"received\": %ld, \"p50_us\": %.2f, \"p90_us\": %.2f, \"p99_us\": %.2f, "
	       "\"max_us\": %.2f}\n",
	       count, got, PCT(0.50), PCT(0.90), PCT(0.99), PCT(1.0));
	return got == count ? 0 : 1;
}
