/* hub.h - the hub's event loop as a library: hub_main.c runs it as the
 * ucan-hub daemon, fuzz/fuzz_hub_state.c drives it in-process (many
 * connections, one loop round at a time). One hub per process. */
#ifndef UCAN_HUB_H
#define UCAN_HUB_H

#include <stdint.h>

#define HUB_DEFAULT_QUEUE_FRAMES 4096

struct hub_options {
	const char *dir;	/* socket directory */
	uint32_t default_queue; /* frames queued per slow reader before drops */
	unsigned spin_us;	/* busy-poll this long after the last event (0: never) */
	int verbose;
};

/* "vcan0" or "vcan1:bitrate=500000,stuffing=exact,mtu=16"; -1 with a logged reason. */
int hub_add_iface(const char *spec);
/* Listening socket, epoll, timers; -1 with a logged reason. */
int hub_start(const struct hub_options *opts);
/* One epoll round (timeout_ms as epoll_wait) and the flush of what it queued; -1 on a fatal error. */
int hub_run_once(int timeout_ms);
/* Rounds until hub_request_stop (async-signal-safe); spins per hub_options.spin_us. */
int hub_run(void);
void hub_request_stop(void);
/* Closes every connection and frees everything, so hub_add_iface/hub_start can run again. */
void hub_shutdown(void);
const char *hub_socket_path(void);
/* Aborts unless what must hold between rounds holds (queues within bounds, flush list empty). */
void hub_check_invariants(void);
void hub_log(const char *fmt, ...) __attribute__((format(printf, 1, 2)));

#endif
