/* zn_stats.c - the node's counters as JSON (the stats queryable and the
 * final stats line), and the monitor that counts reconnections. */
#include <inttypes.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "zn_internal.h"

#define MONITOR_PERIOD_MS 500
#define STATS_JSON_GUESS 4096 /* one bus without a QoS table takes about 1 KiB */

/* Appends at off; past cap it only counts, so the caller learns the length it needs. */
static size_t append(char *buf, size_t cap, size_t off, const char *fmt, ...)
{
	va_list ap;
	va_start(ap, fmt);
	int n = off < cap ? vsnprintf(buf + off, cap - off, fmt, ap) : vsnprintf(NULL, 0, fmt, ap);
	va_end(ap);
	return n < 0 ? off : off + (size_t)n;
}

size_t zn_node_stats_json(char *buf, size_t cap)
{
	size_t off = 0;
	off = append(buf, cap, off,
		     "{\"node\": \"%s\", \"mode\": \"%s\", \"uptime_ms\": %" PRId64 ", \"connected\": %s, "
		     "\"reconnects\": %" PRIu64 ", \"connections_closed\": %" PRIu64 ", \"publish_period_ms\": %" PRIu32
		     ", \"buses\": [",
		     zn_node.cfg.node_name, zn_mode_names[zn_node.cfg.mode], (zn_monotonic_ns() - zn_node.start_ns) / 1000000,
		     READ(zn_node.connected) ? "true" : "false", READ(zn_node.reconnects), zn_connections_closed(zn_node.session),
		     zn_node.cfg.publish_period_ms);
	for (size_t i = 0; i < zn_node.cfg.bus_count; i++) {
		struct bus *b = &zn_node.buses[i];
		uint32_t queued;
		int64_t put_ms;
		zn_rx_gauges(b, &queued, &put_ms);
		off = append(buf, cap, off,
			     "%s{\"bus\": \"%s\", \"rx_key\": \"%s\", \"tx_key\": \"%s\", \"can_rx_frames\": %" PRIu64
			     ", \"filtered\": %" PRIu64 ", \"invalid_frames\": %" PRIu64 ", \"rx_queue_drops\": %" PRIu64
			     ", \"published_samples\": %" PRIu64 ", \"published_frames\": %" PRIu64
			     ", \"publish_errors\": %" PRIu64 ", \"unrouted_frames\": %" PRIu64 ", \"tx_samples\": %" PRIu64 ", \"tx_frames\": %" PRIu64
			     ", \"can_tx_errors\": %" PRIu64 ", \"tx_queue_full\": %" PRIu64 ", \"tx_abandoned\": %" PRIu64
			     ", \"tx_refused_closed\": %" PRIu64 ", \"can_reopens\": %" PRIu64
			     ", \"direct_frames\": %" PRIu64 ", \"direct_stalls\": %" PRIu64
			     ", \"tx_direct_frames\": %" PRIu64 ", \"tx_unstamped\": %" PRIu64
			     ", \"rx_queued\": %" PRIu32 ", \"put_running_ms\": %" PRId64 ", \"tx_rejected\": {",
			     i ? ", " : "", b->name, b->rx_key, b->tx_key, READ(b->n.can_rx_frames), READ(b->n.filtered),
			     READ(b->n.invalid_frames), READ(b->n.rx_queue_drops), READ(b->n.published_samples), READ(b->n.published_frames),
			     READ(b->n.publish_errors), READ(b->n.unrouted_frames), READ(b->n.tx_samples), READ(b->n.tx_frames),
			     READ(b->n.can_tx_errors), READ(b->n.tx_queue_full), READ(b->n.tx_abandoned),
			     READ(zn_tx_refused_closed[i]), READ(b->n.can_reopens), READ(b->n.direct_frames),
			     READ(b->n.direct_stalls),
			     READ(b->n.tx_direct_frames), READ(b->n.tx_unstamped), queued, put_ms);
		for (int r = 1; r < ZN_WIRE_REASONS; r++)
			off = append(buf, cap, off, "%s\"%s\": %" PRIu64, r > 1 ? ", " : "",
				     zn_wire_reason((zn_wire_result_t)-r), READ(b->n.tx_rejected[r]));
		off = append(buf, cap, off, ", \"future\": %" PRIu64 ", \"stale\": %" PRIu64,
			     READ(b->n.tx_rejected_future), READ(b->n.tx_rejected_stale));
		off = append(buf, cap, off, "}");
		/* a QoS table: each class's own count (the totals above hold all classes) */
		for (size_t c = 0; b->qos.class_count > 1 && c < b->qos.class_count; c++) {
			char qos[64];
			zn_qos_describe(&b->qos.classes[c], qos, sizeof(qos));
			off = append(buf, cap, off, "%s{\"qos\": \"%s\", \"published_frames\": %" PRIu64 ", \"rx_queue_drops\": %" PRIu64 "}%s",
				     c ? ", " : ", \"rx_classes\": [", qos, READ(b->ring[c].published_frames),
				     READ(b->ring[c].drops), c + 1 == b->qos.class_count ? "]" : "");
		}
		off = append(buf, cap, off, "}");
	}
	off = append(buf, cap, off, "]}");
	if (off >= cap && cap)
		buf[0] = '\0'; /* never hand out a truncated object */
	return off;
}

char *zn_stats_json_alloc(void)
{
	size_t cap = STATS_JSON_GUESS;
	for (int attempt = 0; attempt < 3; attempt++) { /* counters may grow a digit between two calls */
		char *buf = malloc(cap);
		if (!buf)
			return NULL;
		size_t len = zn_node_stats_json(buf, cap);
		if (len < cap)
			return buf;
		free(buf);
		cap = len + 256;
	}
	return NULL;
}

size_t zn_stats_on_query(char *buf, size_t cap, void *ctx)
{
	(void)ctx;
	/* the gate: undeclaring the queryable does not wait for a callback already running (Zenoh
	 * 1.10), and the buses' locks the stats read are freed once release() sees none inside */
	if (!zn_gate_enter(&zn_stats_gate))
		return 0;
	size_t n = zn_node_stats_json(buf, cap);
	zn_gate_leave(&zn_stats_gate, NULL, NULL); /* release() re-reads the count: stop_lock is its */
	return n;
}

/* Counts reconnections: the router set going away and coming back, or
 * changing identity in between two polls (a router restarted quickly); and
 * says when connections closed, which one replaced within a poll shows alone. */
void zn_stats_monitor_thread(void *arg)
{
	(void)arg;
	char ids[512];
	int announced_wait = 0;
	while (!zn_stop_wait(MONITOR_PERIOD_MS)) {
		zn_poll_connections(zn_node.session);
		int routers = zn_routers(zn_node.session, ids, sizeof(ids));
		int connected = routers > 0 || zn_node.cfg.mode != ZN_MODE_CLIENT; /* peers need no router */
		int was_connected = READ(zn_node.connected);
		int replaced = routers > 0 && zn_node.router_ids[0] && strcmp(ids, zn_node.router_ids) != 0;
		if (connected && (!was_connected || replaced)) {
			if (zn_node.ever_connected) {
				COUNT(zn_node.reconnects);
				zn_log("I", "reconnected to the Zenoh router %s%s", ids, replaced ? " (new router id)" : "");
			} else {
				zn_log("I", "connected (%s mode)%s%s", zn_mode_names[zn_node.cfg.mode], routers ? ", router " : "",
				       routers ? ids : "");
			}
			zn_node.ever_connected = 1;
		} else if (!connected && was_connected) {
			zn_log("W", "lost the Zenoh router; retrying %s", zn_node.cfg.router_address);
		} else if (!connected && !zn_node.ever_connected && !announced_wait) {
			zn_log("I", "waiting for the Zenoh router at %s (retrying)", zn_node.cfg.router_address);
			announced_wait = 1;
		}
		/* a connection replaced within a poll leaves the routers unchanged: only this count sees it */
		uint64_t closed = zn_connections_closed(zn_node.session);
		uint64_t newly = closed > zn_node.connections_seen_closed ? closed - zn_node.connections_seen_closed : 0;
		if (newly)
			zn_log("W", "%" PRIu64 " Zenoh connection%s closed (%" PRIu64 " since start): samples put to its peer before it reopened are lost",
			       newly, newly > 1 ? "s" : "", closed);
		zn_node.connections_seen_closed = closed;
		if (routers > 0)
			snprintf(zn_node.router_ids, sizeof(zn_node.router_ids), "%s", ids);
		__atomic_store_n(&zn_node.connected, connected, __ATOMIC_RELAXED);
	}
}
