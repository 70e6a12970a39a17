/* hop_latency - one-hop latency of a CAN bus: a sender thread writes frames
 * carrying their send time (CLOCK_REALTIME ns); the reader takes its own
 * receipt time (CLOCK_REALTIME, right after recvmsg) and the frame's stamp
 * (SO_TIMESTAMPNS). The stamp is taken once per frame when the frame enters
 * the bus (kernel vcan, and the userspace hub when it takes the frame from the
 * sender; a unix socket when it is sent), so it no longer shows the delivery:
 * the hop is receipt - stamp. receipt - the send time in the frame is printed
 * beside it (it also counts the sender's write). Mode "socketpair" measures
 * the same over a plain unix socketpair: the floor any userspace bus starts
 * from, measured in the same run as the baseline.
 *
 * Usage: hop_latency can <iface> <count> <frames_per_s>
 *        hop_latency socketpair - <count> <frames_per_s>
 * Prints one JSON object: count, received, p50/p90/p99/max of receipt - stamp
 * and send_p50/p99/max of receipt - send time, in microseconds; "stamped": the
 * frames that carried a stamp (one without: its send time stands in). */
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
	int64_t *from_send = calloc((size_t)count, sizeof(*from_send));
	if (!lat || !from_send) {
		perror("calloc");
		return 1;
	}
	long stamped_frames = 0;
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
		int64_t receipt = now_ns(CLOCK_REALTIME); /* first: nothing between recvmsg and the clock */
		int64_t sent, stamp;
		memcpy(&sent, f.data, sizeof(sent));
		stamp = sent;
		for (struct cmsghdr *c = CMSG_FIRSTHDR(&mh); c; c = CMSG_NXTHDR(&mh, c))
			if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SO_TIMESTAMPNS) {
				struct timespec ts;
				memcpy(&ts, CMSG_DATA(c), sizeof(ts));
				stamp = (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
				stamped_frames++;
			}
		from_send[got] = receipt - sent;
		lat[got++] = receipt - stamp;
	}
	pthread_join(tid, NULL);
	qsort(lat, (size_t)got, sizeof(*lat), cmp);
	qsort(from_send, (size_t)got, sizeof(*from_send), cmp);
#define PCT(a, p) (got ? (a)[(long)((got - 1) * (p))] / 1000.0 : -1.0)
	printf("{\"count\": %ld, \"received\": %ld, \"stamped\": %ld, \"p50_us\": %.2f, \"p90_us\": %.2f, "
	       "\"p99_us\": %.2f, \"max_us\": %.2f, \"send_p50_us\": %.2f, \"send_p99_us\": %.2f, "
	       "\"send_max_us\": %.2f}\n",
	       count, got, stamped_frames, PCT(lat, 0.50), PCT(lat, 0.90), PCT(lat, 0.99), PCT(lat, 1.0),
	       PCT(from_send, 0.50), PCT(from_send, 0.99), PCT(from_send, 1.0));
	free(lat);
	free(from_send);
	return got == count ? 0 : 1;
}
