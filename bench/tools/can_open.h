/* The benchmark tools' one way to open a bound CAN_RAW socket (can_load.c,
 * hop_latency.c): exits with the interface's name and the reason on failure,
 * since a benchmark without its bus has nothing to measure. */
#ifndef CAN_OPEN_H
#define CAN_OPEN_H

#include <errno.h>
#include <net/if.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <linux/can.h>
#include <linux/can/raw.h>

static inline int open_can(const char *tool, const char *iface)
{
	int s = socket(PF_CAN, SOCK_RAW, CAN_RAW);
	struct ifreq ifr;
	memset(&ifr, 0, sizeof(ifr));
	snprintf(ifr.ifr_name, sizeof(ifr.ifr_name), "%s", iface);
	if (s < 0 || ioctl(s, SIOCGIFINDEX, &ifr) < 0) {
		fprintf(stderr, "%s: %s: %s\n", tool, iface, strerror(errno));
		exit(1);
	}
	struct sockaddr_can addr = { .can_family = AF_CAN, .can_ifindex = ifr.ifr_ifindex };
	if (bind(s, (struct sockaddr *)&addr, sizeof(addr)) < 0) {
		fprintf(stderr, "%s: bind %s: %s\n", tool, iface, strerror(errno));
		exit(1);
	}
	return s;
}

#endif
