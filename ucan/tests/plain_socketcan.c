/* plain_socketcan - a plain C SocketCAN program, as an application would be
 * written, for the conformance suite: no can-utils, no python-can.
 *
 * Usage: plain_socketcan send <iface> <count>       send ids 0..count-1, 8 data bytes
 *        plain_socketcan recv <iface> <count> [id]  receive count frames (filter on id),
 *                                                   print "<id> <len> <data>" each */
#include <errno.h>
#include <net/if.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <unistd.h>
#include <linux/can.h>
#include <linux/can/raw.h>

#define RECV_TIMEOUT_MS 10000

int main(int argc, char **argv)
{
	if (argc < 4) {
		fprintf(stderr, "Usage: plain_socketcan send|recv <iface> <count> [id]\n");
		return 2;
	}
	long count = strtol(argv[3], NULL, 10);
	int s = socket(PF_CAN, SOCK_RAW, CAN_RAW);
	if (s < 0) {
		perror("socket");
		return 1;
	}
	struct ifreq ifr;
	memset(&ifr, 0, sizeof(ifr));
	snprintf(ifr.ifr_name, sizeof(ifr.ifr_name), "%s", argv[2]);
	if (ioctl(s, SIOCGIFINDEX, &ifr) < 0) {
		perror("SIOCGIFINDEX");
		return 1;
	}
	if (argc > 4) {
		struct can_filter filter = { (canid_t)strtoul(argv[4], NULL, 16), CAN_SFF_MASK | CAN_EFF_FLAG };
		if (setsockopt(s, SOL_CAN_RAW, CAN_RAW_FILTER, &filter, sizeof(filter)) < 0) {
			perror("setsockopt");
			return 1;
		}
	}
	struct sockaddr_can addr = { .can_family = AF_CAN, .can_ifindex = ifr.ifr_ifindex };
	if (bind(s, (struct sockaddr *)&addr, sizeof(addr)) < 0) {
		perror("bind");
		return 1;
	}
	struct can_frame frame;
	if (strcmp(argv[1], "send") == 0) {
		for (long i = 0; i < count; i++) {
			memset(&frame, 0, sizeof(frame));
			frame.can_id = (canid_t)(i & CAN_SFF_MASK);
			frame.len = 8;
			memcpy(frame.data, &i, sizeof(i));
			if (write(s, &frame, sizeof(frame)) != sizeof(frame)) {
				perror("write");
				return 1;
			}
		}
		return 0;
	}
	printf("ready\n");
	fflush(stdout);
	for (long i = 0; i < count; i++) {
		struct pollfd pfd = { .fd = s, .events = POLLIN };
		if (poll(&pfd, 1, RECV_TIMEOUT_MS) != 1) {
			fprintf(stderr, "timeout after %ld frames\n", i);
			return 1;
		}
		ssize_t n = read(s, &frame, sizeof(frame));
		if (n != sizeof(frame)) {
			perror("read");
			return 1;
		}
		printf("%03X %u", frame.can_id, frame.len);
		for (int b = 0; b < frame.len; b++)
			printf(" %02X", frame.data[b]);
		printf("\n");
	}
	close(s);
	return 0;
}
