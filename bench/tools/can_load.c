/* can-load - the benchmarks' CAN side (bench/bus.py,
 * bench/paths.py, bench/callgrind.py, bench/bridge.py).
 *
 *   can-load send IFACES ID RATE COUNT
 *     writes COUNT frames to each interface of IFACES (comma separated; id ID+i
 *     on the i-th), RATE frames/s per interface, all interfaces interleaved;
 *     the 8 data bytes are the send time (CLOCK_REALTIME ns, little endian,
 *     strictly increasing), so any later capture point reads its latency from
 *     the frame itself. Paced by "send what is due, sleep to the next": a
 *     sleep per frame would cap the rate at the timer's slack.
 *   can-load echo IFACE FROM_ID TO_ID COUNT IDLE_MS
 *     an echo ECU: every frame with FROM_ID comes back as TO_ID with the same
 *     data; stops after COUNT frames or IDLE_MS without one.
 *   can-load count IFACES COUNT IDLE_MS
 *     a reader that formats nothing: counts frames on all of IFACES and checks
 *     that each id's stamps only rise (order kept, no duplicates); stops after
 *     COUNT frames in all or IDLE_MS without one.
 *
 * Prints one JSON line (frames, seconds, ENOBUFS retries or order errors). A benchmark load:
 * bounded in count, on the bench's own bus only. */
#define _GNU_SOURCE
#include <errno.h>
#include <poll.h>
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

#define MAX_IFACES 64

static int64_t now_ns(clockid_t clock)
{
	struct timespec ts;
	clock_gettime(clock, &ts);
	return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

static int open_ifaces(char *ifaces, int *fds)
{
	int n = 0;
	for (char *name = strtok(ifaces, ","); name && n < MAX_IFACES; name = strtok(NULL, ","))
		fds[n++] = open_can("can-load", name);
	return n;
}

#define STUCK_NS 10000000000LL /* a bus that takes no frame for this long is gone: the load stops */

/* A full send queue is back-pressure, not an error: wait until it drains, for at most STUCK_NS. */
static void write_frame(int fd, const struct can_frame *f, long *retries)
{
	int64_t since = 0;
	while (write(fd, f, sizeof(*f)) != sizeof(*f)) {
		if (errno != ENOBUFS && errno != EAGAIN && errno != EINTR) {
			perror("can-load: write");
			exit(1);
		}
		if (!since)
			since = now_ns(CLOCK_MONOTONIC);
		else if (now_ns(CLOCK_MONOTONIC) - since > STUCK_NS) {
			fprintf(stderr, "can-load: the bus took no frame for %lld s: stopping\n", STUCK_NS / 1000000000LL);
			exit(1);
		}
		++*retries;
		struct pollfd pfd = { .fd = fd, .events = POLLOUT };
		poll(&pfd, 1, 1);
	}
}

static int send_load(char *ifaces, canid_t id, long rate, long count)
{
	int fds[MAX_IFACES], n = open_ifaces(ifaces, fds);
	long total = count * n, sent = 0, retries = 0;
	int64_t start = now_ns(CLOCK_MONOTONIC), last_stamp = 0;
	double gap_ns = 1e9 / ((double)rate * n);
	while (sent < total) {
		long due = (long)((double)(now_ns(CLOCK_MONOTONIC) - start) / gap_ns) + 1;
		for (; sent < total && sent < due; sent++) {
			struct can_frame f = { .can_id = id + (canid_t)(sent % n), .len = 8 };
			int64_t stamp = now_ns(CLOCK_REALTIME);
			stamp = stamp > last_stamp ? stamp : last_stamp + 1; /* unique: frames are told apart by it */
			last_stamp = stamp;
			memcpy(f.data, &stamp, sizeof(stamp));
			write_frame(fds[sent % n], &f, &retries);
		}
		if (sent < total) {
			int64_t next = start + (int64_t)(gap_ns * (double)sent);
			struct timespec ts = { .tv_sec = next / 1000000000, .tv_nsec = next % 1000000000 };
			while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR)
				;
		}
	}
	double seconds = (double)(now_ns(CLOCK_MONOTONIC) - start) / 1e9;
	printf("{\"frames\": %ld, \"seconds\": %.4f, \"enobufs_retries\": %ld}\n", total, seconds, retries);
	return 0;
}

static int echo(const char *iface, canid_t from, canid_t to, long count, int idle_ms)
{
	int fd = open_can("can-load", iface);
	struct can_filter filter = { .can_id = from, .can_mask = CAN_SFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG };
	int rcvbuf = 8 << 20;
	setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FILTER, &filter, sizeof(filter));
	setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &rcvbuf, sizeof(rcvbuf));
	long echoed = 0, retries = 0;
	int64_t start = now_ns(CLOCK_MONOTONIC);
	while (echoed < count) {
		struct pollfd pfd = { .fd = fd, .events = POLLIN };
		if (poll(&pfd, 1, idle_ms) != 1)
			break;
		struct can_frame f;
		if (read(fd, &f, sizeof(f)) != sizeof(f))
			continue;
		f.can_id = to;
		write_frame(fd, &f, &retries);
		echoed++;
	}
	double seconds = (double)(now_ns(CLOCK_MONOTONIC) - start) / 1e9;
	printf("{\"frames\": %ld, \"seconds\": %.4f, \"enobufs_retries\": %ld}\n", echoed, seconds, retries);
	return 0;
}

/* Per id the stamps must rise: a duplicate or a reordered frame breaks that. The sustained rate
 * a caller wants is frames / (last receive - first stamp), both CLOCK_REALTIME like the stamps. */
static int count_frames(char *ifaces, long count, int idle_ms)
{
	enum { IDS = 256 };
	int fds[MAX_IFACES], n = open_ifaces(ifaces, fds), rcvbuf = 64 << 20;
	struct pollfd pfds[MAX_IFACES];
	for (int i = 0; i < n; i++) {
		setsockopt(fds[i], SOL_SOCKET, SO_RCVBUF, &rcvbuf, sizeof(rcvbuf));
		pfds[i] = (struct pollfd){ .fd = fds[i], .events = POLLIN };
	}
	long got = 0, out_of_order = 0;
	canid_t ids[IDS];
	uint64_t last[IDS], first_stamp = UINT64_MAX;
	int nids = 0;
	int64_t start = 0, last_recv = 0;
	while (got < count) {
		if (poll(pfds, (nfds_t)n, idle_ms) < 1)
			break;
		for (int k = 0; k < n && got < count; k++) {
			if (!(pfds[k].revents & POLLIN))
				continue;
			struct can_frame f;
			/* drain what is queued on this socket, without blocking on it */
			while (got < count && recv(fds[k], &f, sizeof(f), MSG_DONTWAIT) == sizeof(f)) {
				if (f.len != 8)
					continue;
				if (got++ == 0)
					start = now_ns(CLOCK_MONOTONIC);
				last_recv = now_ns(CLOCK_REALTIME);
				uint64_t stamp;
				memcpy(&stamp, f.data, sizeof(stamp));
				first_stamp = stamp < first_stamp ? stamp : first_stamp;
				int i = 0;
				while (i < nids && ids[i] != f.can_id)
					i++;
				if (i == nids && nids < IDS) {
					ids[nids] = f.can_id;
					last[nids++] = 0;
				}
				if (i < nids) {
					out_of_order += stamp <= last[i];
					last[i] = stamp;
				}
			}
		}
	}
	double seconds = got ? (double)(now_ns(CLOCK_MONOTONIC) - start) / 1e9 : 0;
	printf("{\"frames\": %ld, \"seconds\": %.4f, \"out_of_order\": %ld, \"first_stamp_ns\": %llu, "
	       "\"last_recv_ns\": %lld}\n",
	       got, seconds, out_of_order, got ? (unsigned long long)first_stamp : 0ULL, (long long)last_recv);
	return 0;
}

int main(int argc, char **argv)
{
	if (argc == 6 && strcmp(argv[1], "send") == 0) {
		long rate = strtol(argv[4], NULL, 0), count = strtol(argv[5], NULL, 0);
		if (rate > 0 && count > 0)
			return send_load(argv[2], (canid_t)strtoul(argv[3], NULL, 16), rate, count);
	} else if (argc == 7 && strcmp(argv[1], "echo") == 0) {
		long count = strtol(argv[5], NULL, 0);
		int idle_ms = atoi(argv[6]);
		if (count > 0 && idle_ms > 0)
			return echo(argv[2], (canid_t)strtoul(argv[3], NULL, 16), (canid_t)strtoul(argv[4], NULL, 16),
				    count, idle_ms);
	} else if (argc == 5 && strcmp(argv[1], "count") == 0) {
		long count = strtol(argv[3], NULL, 0);
		int idle_ms = atoi(argv[4]);
		if (count > 0 && idle_ms > 0)
			return count_frames(argv[2], count, idle_ms);
	}
	fprintf(stderr, "usage: can-load send IFACES ID_HEX RATE_PER_IFACE COUNT_PER_IFACE\n"
			"       can-load echo IFACE FROM_ID_HEX TO_ID_HEX COUNT IDLE_MS\n"
			"       can-load count IFACES COUNT IDLE_MS\n");
	return 2;
}
