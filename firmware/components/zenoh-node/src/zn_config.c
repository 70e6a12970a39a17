/* zn_config.c - the node's configuration: Kconfig defaults, validation
 * (one line per problem), and the CAN -> Zenoh id filter. */
#include <ctype.h>
#include <inttypes.h>
#include <stdio.h>
#include <string.h>

#include "sdkconfig.h"
#include "zn_node.h"
#include "zn_qos.h"

static void copy_str(char *dst, size_t cap, const char *src)
{
	snprintf(dst, cap, "%s", src ? src : "");
}

#define RX_PRIORITY_DEFAULT 5 /* Zenoh's data priority */

void zn_node_default_config(zn_node_config_t *cfg)
{
	memset(cfg, 0, sizeof(*cfg));
#ifdef CONFIG_ZENOH_NODE_ENABLED
	cfg->enabled = CONFIG_ZENOH_NODE_ENABLED;
#else
	cfg->enabled = false;
#endif
	copy_str(cfg->node_name, sizeof(cfg->node_name), "zenoh-node");
	copy_str(cfg->router_address, sizeof(cfg->router_address), CONFIG_ZENOH_ROUTER_ADDRESS);
	cfg->mode = (zn_mode_t)CONFIG_ZENOH_NODE_MODE;
	cfg->publish_period_ms = CONFIG_ZENOH_PUBLISH_PERIOD_MS;
	cfg->batch_max_frames = CONFIG_ZENOH_BATCH_MAX_FRAMES;
	copy_str(cfg->key_prefix, sizeof(cfg->key_prefix), CONFIG_ZENOH_KEY_PREFIX);
	copy_str(cfg->buses[0], sizeof(cfg->buses[0]), CONFIG_ZENOH_NODE_CAN);
	cfg->bus_count = 1;
	/* telemetry: block rather than let Zenoh drop silently; the node's own
	 * queue bounds memory and counts what it cannot keep */
	/* not express: Zenoh may then put several samples in one write under load. Measured
	 * (docs/benchmark.md): 4x the sustained rate at a third of the CPU per frame, same latency. */
	cfg->rx_qos = (zn_qos_t){ .priority = RX_PRIORITY_DEFAULT, .congestion = ZN_CONGESTION_BLOCK, .express = 0 };
#ifdef CONFIG_ZENOH_RX_QOS
	copy_str(cfg->rx_qos_table, sizeof(cfg->rx_qos_table), CONFIG_ZENOH_RX_QOS);
#endif
	cfg->rx_queue_frames = CONFIG_ZENOH_RX_QUEUE_FRAMES;
	cfg->tx_queue_frames = CONFIG_ZENOH_TX_QUEUE_FRAMES;
#ifdef CONFIG_ZENOH_TX_MAX_AGE_MS
	cfg->tx_max_age_ms = CONFIG_ZENOH_TX_MAX_AGE_MS;
#endif
#ifdef CONFIG_ZENOH_COMPRESSION
	cfg->compression = CONFIG_ZENOH_COMPRESSION;
#endif
#ifdef CONFIG_ZENOH_LOW_LATENCY
	cfg->low_latency = CONFIG_ZENOH_LOW_LATENCY;
#endif
#ifdef CONFIG_ZENOH_ROS2_TOPIC
	copy_str(cfg->ros2_topic, sizeof(cfg->ros2_topic), CONFIG_ZENOH_ROS2_TOPIC);
	cfg->ros2_domain = CONFIG_ZENOH_ROS2_DOMAIN;
#endif
#ifdef CONFIG_ZENOH_ROS2_HUMBLE
	cfg->ros2_humble = true;
#endif
}

/* One chunk of a key expression, of n bytes: none of Zenoh's special characters, no space, nor
 * what the stats' JSON would have to escape (a quote, a backslash, a control character). */
static int valid_key_chunk_n(const char *s, size_t n)
{
	if (!n)
		return 0;
	for (size_t i = 0; i < n; i++)
		if (s[i] == '*' || s[i] == '$' || s[i] == '?' || s[i] == '#' || s[i] == '/' || s[i] == ' ' ||
		    s[i] == '"' || s[i] == '\\' || (unsigned char)s[i] < 0x20)
			return 0;
	return 1;
}

static int valid_key_chunk(const char *s)
{
	return valid_key_chunk_n(s, strlen(s));
}

/* A key prefix: chunks separated by single '/' (no empty chunk: none first, last or between). */
static int valid_key_prefix(const char *s)
{
	for (const char *end;; s = end + 1) {
		end = strchr(s, '/');
		if (!valid_key_chunk_n(s, end ? (size_t)(end - s) : strlen(s)))
			return 0;
		if (!end)
			return 1;
	}
}

/* One Zenoh endpoint: <protocol>/<address>[?metadata][#config], e.g. tcp/127.0.0.1:7447,
 * tls/router.local:7447, [::1] in brackets; an IP protocol needs host:port (port 1..65535). */
static int valid_endpoint(const char *e, size_t n)
{
	static const char *const ip_protocols[] = { "tcp", "udp", "tls", "quic", "ws" };
	static const char *const other_protocols[] = { "unixsock-stream", "unixpipe", "serial", "vsock" };
	const char *slash = memchr(e, '/', n);
	if (!slash || slash == e)
		return 0;
	size_t proto_len = (size_t)(slash - e), addr_len = n - proto_len - 1;
	const char *addr = slash + 1;
	for (size_t i = 0; i < addr_len; i++)
		if (addr[i] == '?' || addr[i] == '#')
			addr_len = i; /* metadata and link configuration follow the address */
	if (addr_len == 0)
		return 0;
	for (size_t i = 0; i < sizeof(other_protocols) / sizeof(other_protocols[0]); i++)
		if (proto_len == strlen(other_protocols[i]) && !memcmp(e, other_protocols[i], proto_len))
			return 1;
	int ip = 0;
	for (size_t i = 0; i < sizeof(ip_protocols) / sizeof(ip_protocols[0]); i++)
		ip |= proto_len == strlen(ip_protocols[i]) && !memcmp(e, ip_protocols[i], proto_len);
	const char *colon = NULL;
	for (size_t i = 0; i < addr_len; i++)
		if (addr[i] == ':')
			colon = addr + i;
	if (!ip || !colon || colon == addr || (addr[0] == '[' && colon[-1] != ']'))
		return 0;
	size_t digits = addr_len - (size_t)(colon + 1 - addr);
	unsigned long port = 0;
	for (size_t i = 0; i < digits; i++) {
		if (!isdigit((unsigned char)colon[1 + i]) || digits > 5)
			return 0;
		port = port * 10 + (unsigned long)(colon[1 + i] - '0');
	}
	return digits > 0 && port >= 1 && port <= 65535;
}

/* Checks a comma-separated endpoint list (empty items are ignored, as the Zenoh port does). */
static int check_endpoints(const char *list, char *err, size_t err_len, const char *what)
{
	for (const char *p = list; *p;) {
		while (*p == ' ' || *p == ',')
			p++;
		size_t n = strcspn(p, ",");
		while (n && p[n - 1] == ' ')
			n--;
		if (n && !valid_endpoint(p, n)) {
			snprintf(err, err_len, "%s endpoint '%.*s' is not <protocol>/<host>:<port> (e.g. tcp/127.0.0.1:7447)",
				 what, (int)n, p);
			return -1;
		}
		p += strcspn(p, ",");
	}
	return 0;
}

esp_err_t zn_node_check_config(const zn_node_config_t *cfg, char *err, size_t err_len)
{
#define BAD(...)                                                                                                       \
	do {                                                                                                           \
		snprintf(err, err_len, __VA_ARGS__);                                                                   \
		return ESP_ERR_INVALID_ARG;                                                                            \
	} while (0)
	if (cfg->mode > ZN_MODE_ROUTER)
		BAD("mode %d is not 0 (client), 1 (peer) or 2 (router)", (int)cfg->mode);
	if (cfg->mode == ZN_MODE_CLIENT && !cfg->router_address[0])
		BAD("client mode needs a router address (ZENOH_ROUTER_ADDRESS / --router)");
	if (check_endpoints(cfg->router_address, err, err_len, "router") != 0 ||
	    check_endpoints(cfg->listen, err, err_len, "listen") != 0)
		return ESP_ERR_INVALID_ARG;
	if (cfg->publish_period_ms > 60000)
		BAD("publish period %" PRIu32 " ms is over 60000 ms", cfg->publish_period_ms);
	if (cfg->batch_max_frames < 1 || cfg->batch_max_frames > ZN_BATCH_MAX_FRAMES)
		BAD("batch max %" PRIu32 " frames is not 1..%d", cfg->batch_max_frames, ZN_BATCH_MAX_FRAMES);
	if (cfg->rx_queue_frames < 16 || cfg->rx_queue_frames > 1048576)
		BAD("rx queue %" PRIu32 " frames is not 16..1048576", cfg->rx_queue_frames);
	if (cfg->tx_queue_frames < ZN_BATCH_MAX_FRAMES || cfg->tx_queue_frames > 65536)
		BAD("tx queue %" PRIu32 " frames is not %d..65536 (it holds at least one largest command)",
		    cfg->tx_queue_frames, ZN_BATCH_MAX_FRAMES);
	if (cfg->tx_max_age_ms > 60000)
		BAD("tx max age %" PRIu32 " ms is over 60000 ms (0 = off)", cfg->tx_max_age_ms);
	if (cfg->bus_count < 1 || cfg->bus_count > ZN_MAX_BUSES)
		BAD("%zu CAN buses: 1..%d supported", cfg->bus_count, ZN_MAX_BUSES);
	if (!valid_key_chunk(cfg->node_name))
		BAD("node name '%s' must be one key chunk (no '/', '*', '$', '?', '#', spaces, quotes, backslashes)",
		    cfg->node_name);
	if (!valid_key_prefix(cfg->key_prefix))
		BAD("key prefix '%s' must be a plain key expression (chunks without '*', '$', '?', '#', spaces, quotes, "
		    "backslashes; no leading, trailing or double '/')",
		    cfg->key_prefix);
	for (size_t i = 0; i < cfg->bus_count; i++) {
		if (!valid_key_chunk(cfg->buses[i]))
			BAD("CAN bus name '%s' must be one key chunk", cfg->buses[i]);
		for (size_t j = 0; j < i; j++)
			if (strcmp(cfg->buses[i], cfg->buses[j]) == 0)
				BAD("CAN bus '%s' given twice", cfg->buses[i]);
	}
	if (cfg->ros2_topic[0]) {
		size_t n = strlen(cfg->ros2_topic);
		if (cfg->ros2_topic[0] != '/' || n < 2 || cfg->ros2_topic[n - 1] == '/')
			BAD("ROS 2 topic '%s' must be absolute, like /vehicle/can", cfg->ros2_topic);
		for (const char *c = cfg->ros2_topic; *c; c++)
			if (!(isalnum((unsigned char)*c) || *c == '_' || *c == '/') || (c[0] == '/' && c[1] == '/'))
				BAD("ROS 2 topic '%s': only letters, digits, '_' and single '/'", cfg->ros2_topic);
	}
	if (cfg->ros2_domain > 232)
		BAD("ROS 2 domain %" PRIu32 " is not 0..232", cfg->ros2_domain);
	if (cfg->rx_qos.priority < 1 || cfg->rx_qos.priority > 7)
		BAD("priority %u is not 1 (real time) .. 7 (background)", cfg->rx_qos.priority);
	zn_qos_table_t qos;
	if (zn_qos_parse(cfg->rx_qos_table, &cfg->rx_qos, &qos, err, err_len) != 0)
		return ESP_ERR_INVALID_ARG;
	/* the low-latency transport writes every sample at once, reliably, with no priorities and no
	 * compression: a setting it cannot honour is refused, not silently ignored */
	if (cfg->low_latency && (cfg->rx_qos_table[0] || cfg->rx_qos.priority != RX_PRIORITY_DEFAULT ||
				 cfg->rx_qos.congestion != ZN_CONGESTION_BLOCK || cfg->rx_qos.best_effort))
		BAD("low latency: Zenoh's low-latency transport has no QoS; leave the rx QoS table, priority "
		    "and congestion control at their defaults");
	if (cfg->low_latency && cfg->compression)
		BAD("low latency: Zenoh's low-latency transport does not compress; turn compression off");
	const zn_id_range_t *lists[2] = { cfg->allow, cfg->deny };
	size_t counts[2] = { cfg->allow_count, cfg->deny_count };
	for (int l = 0; l < 2; l++)
		for (size_t i = 0; i < counts[l]; i++) {
			const zn_id_range_t *r = &lists[l][i];
			uint32_t max = r->extended ? CAN_EXTD_ID_MASK : CAN_STD_ID_MASK;
			if (r->first > r->last || r->last > max)
				BAD("id range 0x%" PRIX32 "-0x%" PRIX32 " is empty or beyond 0x%" PRIX32, r->first, r->last,
				    max);
		}
	return ESP_OK;
#undef BAD
}

static bool range_match(const zn_id_range_t *r, size_t n, const can_message_t *msg)
{
	for (size_t i = 0; i < n; i++)
		if ((bool)msg->extd == r[i].extended && msg->identifier >= r[i].first && msg->identifier <= r[i].last)
			return true;
	return false;
}

bool zn_node_id_allowed(const zn_node_config_t *cfg, const can_message_t *msg)
{
	if (cfg->allow_count && !range_match(cfg->allow, cfg->allow_count, msg))
		return false;
	return !range_match(cfg->deny, cfg->deny_count, msg);
}
