/* ucan-hub - userspace SocketCAN bus daemon: serves virtual CAN interfaces to
 * programs running under libucan-preload.so (docs/userspace-bus.md).
 *
 * Usage: ucan-hub [-d dir] [-q frames] [-r fd] [-s usec] [-v] [iface[:opt=val,...]]...
 *   iface options: bitrate=<bit/s> (0 = unthrottled, vcan behaviour),
 *                  stuffing=worst|exact|none, mtu=16|72
 *   example: ucan-hub -d /run/ucan vcan0 vcan1:bitrate=500000,stuffing=exact,mtu=16 */
#define _GNU_SOURCE
#include <errno.h>
#include <getopt.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "canfilter.h"
#include "hub.h"
#include "ucan_proto.h"

static void usage(void)
{
	fprintf(stderr,
		"Usage: ucan-hub [-d dir] [-q frames] [-r fd] [-s usec] [-v] [iface[:opt=val,...]]...\n"
		"  -d dir     socket directory (default $" UCAN_DIR_ENV " or " UCAN_DEFAULT_DIR ")\n"
		"  -q frames  frames queued per slow reader before drops (default %d)\n"
		"  -r fd      write \"ready\\n\" to fd once accepting connections\n"
		"  -s usec    busy-poll this long after the last event before sleeping: lower\n"
		"             latency for a core's worth of CPU while busy (default 0: never spin)\n"
		"  -v         log connections\n"
		"  iface options: bitrate=<bit/s>, stuffing=worst|exact|none, mtu=16|72\n"
		"  default interface: vcan0 (unthrottled, mtu 72, like kernel vcan)\n",
		HUB_DEFAULT_QUEUE_FRAMES);
}

static void on_signal(int sig)
{
	(void)sig;
	hub_request_stop();
}

int main(int argc, char **argv)
{
	struct hub_options opts = { .default_queue = HUB_DEFAULT_QUEUE_FRAMES };
	int opt, ready_fd = -1;
	char *end;

	opts.dir = getenv(UCAN_DIR_ENV);
	if (!opts.dir || !*opts.dir)
		opts.dir = UCAN_DEFAULT_DIR;
	while ((opt = getopt(argc, argv, "d:q:r:s:vh")) != -1) {
		switch (opt) {
		case 'd':
			opts.dir = optarg;
			break;
		case 'q': {
			unsigned long q = strtoul(optarg, &end, 10);
			if (*end || q < 1 || q > 10000000ul) {
				hub_log("-q '%s' is not 1..10000000 frames", optarg);
				return 2;
			}
			opts.default_queue = (uint32_t)q;
			break;
		}
		case 'r':
			ready_fd = (int)strtol(optarg, &end, 10);
			if (*end || ready_fd < 0) {
				hub_log("-r '%s' is not a file descriptor", optarg);
				return 2;
			}
			break;
		case 's': {
			unsigned long us = strtoul(optarg, &end, 10);
			if (*end || us > 1000000ul) {
				hub_log("-s '%s' is not 0..1000000 microseconds", optarg);
				return 2;
			}
			opts.spin_us = (unsigned)us;
			break;
		}
		case 'v':
			opts.verbose = 1;
			break;
		default:
			usage();
			return opt == 'h' ? 0 : 2;
		}
	}
	for (int i = optind; i < argc; i++)
		if (hub_add_iface(argv[i]) < 0)
			return 2;
	const char *test_fault = getenv("UCAN_HUB_TEST_FAULT");
	if (test_fault && strcmp(test_fault, "ignore-rtr-filter") == 0) {
		can_filter_test_ignore_rtr = 1;
		hub_log("TEST FAULT: filters ignore the RTR bit (UCAN_HUB_TEST_FAULT)");
	}

	struct sigaction sa = { .sa_handler = on_signal };
	sigaction(SIGINT, &sa, NULL);
	sigaction(SIGTERM, &sa, NULL);
	signal(SIGPIPE, SIG_IGN);

	if (hub_start(&opts) < 0)
		return 1;
	if (ready_fd >= 0) {
		if (write(ready_fd, "ready\n", 6) < 0)
			hub_log("readiness fd %d: %s", ready_fd, strerror(errno));
		close(ready_fd);
	}
	int rc = hub_run();
	hub_shutdown();
	return rc < 0 ? 1 : 0;
}
