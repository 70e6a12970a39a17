/* can_enobufs.c - the Linux CAN port's writers against a tx queue that stays full while poll()
 * says writable, as a real interface's does on ENOBUFS (a bus without an ACK, bus-off): send and
 * sendmmsg are wrapped (-Wl,--wrap) to fail with ENOBUFS for HOLD_MS, then pass through to the
 * bus. Sends one frame (zn_can_transmit) and a burst of three (zn_can_send_burst), each after a
 * hold, and prints the attempts each made during its hold: tests/bridge/test_can_port.py runs it
 * on the bus and bounds them (a writer that retried at once made thousands a ms).
 *
 *   usage: can-enobufs IFACE HOLD_MS      e.g. can-enobufs vcan0 50
 *   prints: single attempts=N rc=0
 *           burst attempts=N rc=0 sent=3 */
#define _GNU_SOURCE
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/socket.h>

#include "zn_port_can.h"
#include "zn_port_os.h"

#define TRANSMIT_TIMEOUT_MS 2000 /* far beyond any hold: the write must wait it out, not give up */

static int64_t hold_until_ns;
static long attempts;

static int held(void)
{
	if (zn_monotonic_ns() >= hold_until_ns)
		return 0;
	attempts++;
	errno = ENOBUFS;
	return 1;
}

ssize_t __real_send(int fd, const void *buf, size_t len, int flags);
ssize_t __wrap_send(int fd, const void *buf, size_t len, int flags)
{
	return held() ? -1 : __real_send(fd, buf, len, flags);
}

int __real_sendmmsg(int fd, struct mmsghdr *vec, unsigned int n, int flags);
int __wrap_sendmmsg(int fd, struct mmsghdr *vec, unsigned int n, int flags)
{
	return held() ? -1 : __real_sendmmsg(fd, vec, n, flags);
}

static void hold(int hold_ms)
{
	attempts = 0;
	hold_until_ns = zn_monotonic_ns() + (int64_t)hold_ms * 1000000;
}

int main(int argc, char **argv)
{
	if (argc != 3 || atoi(argv[2]) <= 0) {
		fprintf(stderr, "usage: %s IFACE HOLD_MS\n", argv[0]);
		return 2;
	}
	int hold_ms = atoi(argv[2]);
	zn_can_t *can;
	if (zn_can_open(argv[1], &can) != ESP_OK) {
		perror("zn_can_open");
		return 1;
	}
	can_message_t one = { .identifier = 0x321, .data_length_code = 2, .data = { 0xAB, 0xCD } };
	hold(hold_ms);
	esp_err_t rc = zn_can_transmit(can, &one, TRANSMIT_TIMEOUT_MS);
	printf("single attempts=%ld rc=%d\n", attempts, rc);
	can_message_t three[3] = {
		{ .identifier = 0x322, .data_length_code = 1, .data = { 1 } },
		{ .identifier = 0x323, .data_length_code = 1, .data = { 2 } },
		{ .identifier = 0x324, .data_length_code = 1, .data = { 3 } },
	};
	size_t sent = 0;
	hold(hold_ms);
	esp_err_t burst_rc = zn_can_send_burst(can, three, 3, &sent, TRANSMIT_TIMEOUT_MS);
	printf("burst attempts=%ld rc=%d sent=%zu\n", attempts, burst_rc, sent);
	zn_can_close(can);
	return rc == ESP_OK && burst_rc == ESP_OK && sent == 3 ? 0 : 1;
}
