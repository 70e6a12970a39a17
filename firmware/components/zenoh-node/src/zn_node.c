/* zn_node.c - the node's lifecycle: init declares everything and starts the
 * threads (the liveliness token last: when it is visible the bridge forwards
 * both ways); stop withdraws the tokens first, flushes, and frees. */
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "zn_internal.h"

#define STATS_RECHECK_MS 1 /* release() re-reads the stats gate's count at least this often */

struct node zn_node;
struct zn_gate zn_cb_gates[ZN_MAX_BUSES], zn_stats_gate;
uint64_t zn_tx_refused_closed[ZN_MAX_BUSES];
const char *const zn_mode_names[3] = { "client", "peer", "router" };

int zn_stop_wait(int timeout_ms)
{
	zn_mutex_lock(zn_node.stop_lock);
	if (!zn_node.stopping)
		zn_cond_wait(zn_node.stop_cond, zn_node.stop_lock, timeout_ms);
	int stopping = zn_node.stopping;
	zn_mutex_unlock(zn_node.stop_lock);
	return stopping;
}

static esp_err_t init_bus(struct bus *b, size_t index)
{
	const zn_node_config_t *cfg = &zn_node.cfg;
	b->index = index;
	b->name = cfg->buses[index];
	if (cfg->bus_count == 1) {
		snprintf(b->rx_key, sizeof(b->rx_key), "%s/rx", cfg->key_prefix);
		snprintf(b->tx_key, sizeof(b->tx_key), "%s/tx", cfg->key_prefix);
	} else {
		snprintf(b->rx_key, sizeof(b->rx_key), "%s/%s/rx", cfg->key_prefix, b->name);
		snprintf(b->tx_key, sizeof(b->tx_key), "%s/%s/tx", cfg->key_prefix, b->name);
	}
	snprintf(b->token_key, sizeof(b->token_key), "%s/bridges/%s/%s/%s", cfg->key_prefix, cfg->node_name, b->name,
		 zn_mode_names[cfg->mode]);
	ZN_TRY(zn_rx_queue_init(b));
	/* the sample the publisher builds: one frame in immediate mode, else a batch */
	size_t batch_max = cfg->publish_period_ms ? cfg->batch_max_frames : 1;
	b->payload = malloc(batch_max * ZN_WIRE_FRAME_SIZE);
	b->attachment = malloc(ZN_ATTACHMENT_SIZE(batch_max));
	if (!b->payload || !b->attachment || zn_tx_queue_init(b, cfg->tx_queue_frames) != ESP_OK)
		return ESP_ERR_NO_MEM;
	ZN_TRY(zn_mutex_new(&b->lock));
	ZN_TRY(zn_mutex_new(&b->can_lock));
	ZN_TRY(zn_cond_new(&b->nonempty));
	ZN_TRY(zn_cond_new(&b->handback));
	ZN_TRY(zn_mutex_new(&b->tx_lock));
	ZN_TRY(zn_cond_new(&b->tx_ready));
	ZN_TRY(zn_cond_new(&b->tx_idle));
	if (zn_can_open(b->name, &b->can) != ESP_OK) {
		zn_log("E", "cannot open CAN bus %s", b->name);
		return ESP_FAIL;
	}
	if (zn_rx_declare(b) != 0 ||
	    zn_declare_subscriber(zn_node.session, b->tx_key, zn_tx_on_command, b, &b->sub) != 0) {
		zn_log("E", "cannot declare %s / %s", b->rx_key, b->tx_key);
		return ESP_FAIL;
	}
	if (cfg->ros2_topic[0])
		ZN_TRY(zn_ros2_declare_bus(b));
	return ESP_OK;
}

/* Withdraws the tokens (nobody should send commands to a bridge on its way out) and closes
 * the command subscribers: no callback is inside a tx queue once this returns. */
static void withdraw(void)
{
	for (size_t i = 0; i < zn_node.cfg.bus_count; i++) {
		struct bus *b = &zn_node.buses[i];
		zn_undeclare_token(b->token);
		zn_undeclare_token(b->ros_token);
		b->token = b->ros_token = NULL;
	}
	zn_undeclare_token(zn_node.ros_node_token);
	zn_node.ros_node_token = NULL;
	for (size_t i = 0; i < zn_node.cfg.bus_count; i++)
		zn_tx_close(&zn_node.buses[i]);
}

/* Undeclares, closes and frees whatever init took (all of it after a stop, part of it after
 * a failed init: every handle may be NULL). The threads are stopped. */
static void release(int final_stats)
{
	withdraw();
	for (size_t i = 0; i < zn_node.cfg.bus_count; i++) {
		struct bus *b = &zn_node.buses[i];
		zn_rx_undeclare(b);
		if (b->ros_pub)
			zn_undeclare_publisher(b->ros_pub);
	}
	zn_gate_shut(&zn_stats_gate);
	zn_undeclare_queryable(zn_node.stats_q);
	/* one Zenoh started before the gate shut may still read the buses' locks */
	zn_gate_wait(&zn_stats_gate, zn_node.stop_lock, zn_node.stop_cond, STATS_RECHECK_MS);
	char *stats = final_stats ? zn_stats_json_alloc() : NULL;
	if (stats)
		zn_log("I", "final stats: %s", stats);
	free(stats);
	zn_close(zn_node.session);
	for (size_t i = 0; i < zn_node.cfg.bus_count; i++) {
		struct bus *b = &zn_node.buses[i];
		zn_can_close(b->can);
		zn_rx_queue_free(b);
		free(b->txq);
		free(b->tx_heap);
		free(b->tx_burst);
		free(b->tx_group);
		free(b->payload);
		free(b->attachment);
		zn_cond_free(b->nonempty);
		zn_cond_free(b->handback);
		zn_cond_free(b->tx_ready);
		zn_cond_free(b->tx_idle);
		zn_mutex_free(b->tx_lock);
		zn_mutex_free(b->lock);
		zn_mutex_free(b->can_lock);
	}
	zn_cond_free(zn_node.stop_cond);
	zn_mutex_free(zn_node.stop_lock);
	memset(&zn_node, 0, sizeof(zn_node)); /* the gates stay shut: a callback Zenoh runs this late touches nothing */
}

static void shut_gates(void)
{
	for (size_t i = 0; i < ZN_MAX_BUSES; i++)
		zn_gate_shut(&zn_cb_gates[i]);
	zn_gate_shut(&zn_stats_gate);
}

/* Everything init does once the configuration is valid; on failure, what it took is released by the caller. */
static esp_err_t start(const zn_node_config_t *cfg)
{
	zn_node.start_ns = zn_monotonic_ns();
	ZN_TRY(zn_mutex_new(&zn_node.stop_lock));
	ZN_TRY(zn_cond_new(&zn_node.stop_cond));

	zn_session_config_t scfg = {
		.mode = cfg->mode,
		.connect = cfg->router_address,
		.listen = cfg->listen,
		.config_file = cfg->zenoh_config_file[0] ? cfg->zenoh_config_file : NULL,
		.compression = cfg->compression,
		.rx_message_max = ZN_RX_MESSAGE_MAX,
		.low_latency = cfg->low_latency,
	};
	int open_rc = zn_open(&scfg, &zn_node.session);
	if (open_rc == ZN_PORT_ERR_CONFIG)
		return ESP_ERR_INVALID_ARG; /* a configuration error, its reason logged by the port: exit code 2 */
	if (open_rc != 0) {
		zn_log("E", "cannot open the Zenoh session");
		return ESP_FAIL;
	}
	/* the routers we start with: a replacement seen by the first poll is a reconnect; and the
	 * first of the connection polls, so one refused during the open is dropped at the monitor's first */
	zn_poll_connections(zn_node.session);
	int routers = zn_routers(zn_node.session, zn_node.router_ids, sizeof(zn_node.router_ids));
	zn_node.connected = zn_node.ever_connected = routers > 0 || cfg->mode != ZN_MODE_CLIENT;
	if (zn_node.ever_connected)
		zn_log("I", "connected (%s mode)%s%s", zn_mode_names[cfg->mode], routers > 0 ? ", router " : "",
		       routers > 0 ? zn_node.router_ids : "");
	for (size_t i = 0; i < cfg->bus_count; i++)
		ZN_TRY(init_bus(&zn_node.buses[i], i));
	snprintf(zn_node.stats_key, sizeof(zn_node.stats_key), "%s/bridges/%s/stats", cfg->key_prefix, cfg->node_name);
	if (zn_declare_queryable(zn_node.session, zn_node.stats_key, zn_stats_on_query, NULL, &zn_node.stats_q) != 0) {
		zn_log("E", "cannot declare the stats queryable %s", zn_node.stats_key);
		return ESP_FAIL;
	}
	zn_gate_open(&zn_stats_gate); /* what it reads exists */
	/* ROS 2's tokens and the gid its samples carry: before the threads that publish start, and
	 * before the bridge's token (other clients may still see tokens in another order) */
	char zid[64] = "";
	zn_session_id(zn_node.session, zid, sizeof(zid));
	if (cfg->ros2_topic[0] && zn_ros2_declare_tokens(zid) != ESP_OK)
		return ESP_FAIL;
	zn_node.running = 1;
	for (size_t i = 0; i < cfg->bus_count; i++) {
		struct bus *b = &zn_node.buses[i];
		ZN_TRY(zn_thread_start(&b->publisher, "zn-pub", zn_rx_publisher_thread, b));
		ZN_TRY(zn_thread_start(&b->reader, "zn-can", zn_rx_reader_thread, b));
		ZN_TRY(zn_thread_start(&b->transmitter, "zn-tx", zn_tx_transmitter_thread, b));
	}
	ZN_TRY(zn_thread_start(&zn_node.monitor, "zn-mon", zn_stats_monitor_thread, NULL));
	/* commands are taken from now on: a start that failed before wrote none */
	for (size_t i = 0; i < cfg->bus_count; i++)
		zn_gate_open(&zn_cb_gates[i]);
	/* last: the token tells others the bridge forwards both ways from now on */
	for (size_t i = 0; i < cfg->bus_count; i++) {
		struct bus *b = &zn_node.buses[i];
		if (zn_declare_token(zn_node.session, b->token_key, &b->token) != 0) {
			zn_log("E", "cannot declare the liveliness token %s", b->token_key);
			return ESP_FAIL;
		}
		zn_log("I", "bridging %s: CAN -> %s, %s -> CAN (token %s)", b->name, b->rx_key, b->tx_key, b->token_key);
	}
	zn_log("I", "ready: zid %s, mode %s, publish period %" PRIu32 " ms, stats on %s", zid, zn_mode_names[cfg->mode],
	       cfg->publish_period_ms, zn_node.stats_key);
	return ESP_OK;
}

esp_err_t zn_node_init(const zn_node_config_t *cfg)
{
	char err[256];
	if (zn_node.running)
		return ESP_ERR_INVALID_STATE;
	if (zn_node_check_config(cfg, err, sizeof(err)) != ESP_OK) {
		zn_log("E", "invalid configuration: %s", err);
		return ESP_ERR_INVALID_ARG;
	}
	shut_gates(); /* until start has succeeded; a callback of an earlier session finds them shut */
	for (size_t i = 0; i < ZN_MAX_BUSES; i++) /* one turned away from now on is this session's to report */
		__atomic_store_n(&zn_tx_refused_closed[i], 0, __ATOMIC_RELAXED);
	memset(&zn_node, 0, sizeof(zn_node));
	zn_node.cfg = *cfg;
	esp_err_t rc = start(cfg);
	if (rc != ESP_OK) {
		if (zn_node.running)
			zn_node_stop(); /* threads were started: stop them as on shutdown */
		else
			release(0);
	}
	return rc;
}

void zn_node_stop(void)
{
	if (!zn_node.running)
		return;
	withdraw();
	zn_mutex_lock(zn_node.stop_lock);
	zn_node.stopping = 1;
	zn_cond_signal(zn_node.stop_cond);
	zn_mutex_unlock(zn_node.stop_lock);
	for (size_t i = 0; i < zn_node.cfg.bus_count; i++) {
		struct bus *b = &zn_node.buses[i];
		zn_thread_join(b->reader);
		zn_mutex_lock(b->lock);
		b->reader_gone = 1;
		zn_cond_signal(b->nonempty);
		zn_mutex_unlock(b->lock);
		zn_thread_join(b->publisher); /* flushes the pending batch */
		zn_mutex_lock(b->tx_lock);
		b->tx_stop = 1;
		zn_cond_signal(b->tx_ready);
		zn_mutex_unlock(b->tx_lock);
		zn_thread_join(b->transmitter); /* writes what is queued while the bus takes it */
	}
	zn_thread_join(zn_node.monitor);
	release(1);
}
