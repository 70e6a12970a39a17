/* zn_config_parse.c - see zn_config_parse.h. */
#define _GNU_SOURCE
#include "zn_config_parse.h"

#include <errno.h>
#include <getopt.h>
#include <inttypes.h>
#include <stdlib.h>
#include <string.h>

enum opt_id {
	OPT_ENABLED = 256, OPT_ROUTER, OPT_LISTEN, OPT_MODE, OPT_PERIOD, OPT_BATCH, OPT_PREFIX, OPT_NAME, OPT_CAN,
	OPT_ALLOW, OPT_DENY, OPT_RX_PRIORITY, OPT_RX_CONGESTION, OPT_RX_EXPRESS, OPT_RX_QUEUE, OPT_TX_QUEUE, OPT_ZENOH_CONFIG,
	OPT_COMPRESSION, OPT_ROS2_TOPIC, OPT_ROS2_DOMAIN, OPT_TX_MAX_AGE, OPT_RX_QOS, OPT_LOW_LATENCY, OPT_ROS2_HUMBLE,
	OPT_HELP,
};

struct option_spec {
	enum opt_id id;
	const char *flag, *env, *arg, *help;
};

static const struct option_spec specs[] = {
	{ OPT_ENABLED, "enabled", "ZENOH_NODE_ENABLED", "0|1", "start the bridge (Kconfig ZENOH_NODE_ENABLED)" },
	{ OPT_ROUTER, "router", "ZENOH_ROUTER_ADDRESS", "ENDPOINTS", "connect endpoints, comma separated (default tcp/127.0.0.1:7447)" },
	{ OPT_LISTEN, "listen", "ZENOH_LISTEN", "ENDPOINTS", "listen endpoints (peer/router mode)" },
	{ OPT_MODE, "mode", "ZENOH_NODE_MODE", "MODE", "client|peer|router or 0|1|2 (default client)" },
	{ OPT_PERIOD, "publish-period-ms", "ZENOH_PUBLISH_PERIOD_MS", "MS", "batch period; 0 = publish each frame at once (default 100)" },
	{ OPT_BATCH, "batch-max-frames", "ZENOH_BATCH_MAX_FRAMES", "N", "publish a batch early at N frames (default 256)" },
	{ OPT_PREFIX, "key-prefix", "ZENOH_KEY_PREFIX", "KEY", "key prefix (default vehicle/can)" },
	{ OPT_NAME, "name", "ZENOH_NODE_NAME", "NAME", "node name in tokens and stats (default zenoh-node)" },
	{ OPT_CAN, "can", "ZENOH_NODE_CAN", "BUSES", "CAN interfaces, comma separated (default vcan0)" },
	{ OPT_ALLOW, "allow-ids", "ZENOH_NODE_ALLOW_IDS", "RANGES", "bridge only these ids to Zenoh, e.g. 100-1FF,e:18DA0000-18DAFFFF" },
	{ OPT_DENY, "deny-ids", "ZENOH_NODE_DENY_IDS", "RANGES", "never bridge these ids (deny wins over allow)" },
	{ OPT_RX_PRIORITY, "rx-priority", "ZENOH_RX_PRIORITY", "1-7", "Zenoh priority of CAN -> Zenoh samples (default 5, data)" },
	{ OPT_RX_CONGESTION, "rx-congestion", "ZENOH_RX_CONGESTION", "block|drop", "Zenoh congestion control of CAN -> Zenoh (default block)" },
	{ OPT_RX_EXPRESS, "rx-express", "ZENOH_RX_EXPRESS", "0|1", "send CAN -> Zenoh samples without Zenoh batching (default 0)" },
	{ OPT_RX_QUEUE, "rx-queue-frames", "ZENOH_RX_QUEUE_FRAMES", "N", "frames queued between CAN reader and publisher (default 65536)" },
	{ OPT_TX_QUEUE, "tx-queue-frames", "ZENOH_TX_QUEUE_FRAMES", "N", "command frames queued for CAN; a command that does not fit is refused (default 2048)" },
	{ OPT_ZENOH_CONFIG, "zenoh-config", "ZENOH_CONFIG", "FILE", "Zenoh JSON5 config applied first (TLS, auth)" },
	{ OPT_COMPRESSION, "compression", "ZENOH_COMPRESSION", "0|1", "compress the Zenoh transport (default 0)" },
	{ OPT_ROS2_TOPIC, "ros2-topic", "ZENOH_ROS2_TOPIC", "TOPIC", "also publish can_msgs/msg/Frame on this ROS 2 topic (default off)" },
	{ OPT_ROS2_DOMAIN, "ros2-domain", "ZENOH_ROS2_DOMAIN", "N", "ROS_DOMAIN_ID of that topic (default 0)" },
	{ OPT_ROS2_HUMBLE, "ros2-humble", "ZENOH_ROS2_HUMBLE", "0|1", "that topic as Humble's rmw_zenoh keys it: TypeHashNotSupported, no type hash (default 0)" },
	{ OPT_TX_MAX_AGE, "tx-max-age-ms", "ZENOH_TX_MAX_AGE_MS", "MS", "refuse commands older than MS (source time: attachment, else Zenoh timestamp); 0 = off (default 0)" },
	{ OPT_RX_QOS, "rx-qos", "ZENOH_RX_QOS", "TABLE", "CAN -> Zenoh QoS per id range, e.g. 0x000-0x0FF:realtime,express;0x100-0x7FF:data,best-effort (default none)" },
	{ OPT_LOW_LATENCY, "low-latency", "ZENOH_LOW_LATENCY", "0|1", "Zenoh's low-latency transport, no QoS; the router must enable it too (default 0)" },
	{ OPT_HELP, "help", NULL, NULL, "this help" },
};
#define NSPECS (sizeof(specs) / sizeof(specs[0]))

void zn_config_usage(FILE *out)
{
	fprintf(out, "Usage: zenoh-node [options]\nEach option can also be set by its environment variable.\n\n");
	for (size_t i = 0; i < NSPECS; i++) {
		char left[64];
		snprintf(left, sizeof(left), "--%s%s%s", specs[i].flag, specs[i].arg ? " " : "",
			 specs[i].arg ? specs[i].arg : "");
		fprintf(out, "  %-32s %s%s%s%s\n", left, specs[i].help, specs[i].env ? " [" : "",
			specs[i].env ? specs[i].env : "", specs[i].env ? "]" : "");
	}
}

static int parse_u32(const char *text, uint32_t *out)
{
	char *end;
	errno = 0;
	unsigned long long v = strtoull(text, &end, 0);
	if (errno || end == text || *end || text[0] == '-' || v > UINT32_MAX)
		return -1;
	*out = (uint32_t)v;
	return 0;
}

static int parse_bool(const char *text, bool *out)
{
	if (!strcmp(text, "1") || !strcmp(text, "true") || !strcmp(text, "yes") || !strcmp(text, "y")) {
		*out = true;
		return 0;
	}
	if (!strcmp(text, "0") || !strcmp(text, "false") || !strcmp(text, "no") || !strcmp(text, "n")) {
		*out = false;
		return 0;
	}
	return -1;
}

int zn_parse_id_ranges(const char *text, zn_id_range_t *out, size_t max, size_t *count, char *err, size_t err_len)
{
	char buf[1024];
	char *save = NULL;
	*count = 0;
	if (snprintf(buf, sizeof(buf), "%s", text) >= (int)sizeof(buf)) {
		snprintf(err, err_len, "id ranges too long");
		return -1;
	}
	for (char *tok = strtok_r(buf, ",", &save); tok; tok = strtok_r(NULL, ",", &save)) {
		zn_id_range_t r = { 0 };
		char *p = tok, *end;
		while (*p == ' ')
			p++;
		if (!strncmp(p, "e:", 2)) {
			r.extended = true;
			p += 2;
		}
		errno = 0;
		unsigned long long first = strtoull(p, &end, 16), last = first;
		if (end == p || errno || *p == '-')
			goto bad;
		if (*end == '-') {
			char *q = end + 1;
			last = strtoull(q, &end, 16);
			if (end == q || errno || *q == '-')
				goto bad;
		}
		while (*end == ' ')
			end++;
		if (*end)
			goto bad;
		if (*count == max) {
			snprintf(err, err_len, "more than %zu id ranges", max);
			return -1;
		}
		if (first > CAN_EXTD_ID_MASK || last > CAN_EXTD_ID_MASK) { /* never cut to 32 bits */
			snprintf(err, err_len, "id range '%s' is beyond 0x%X (29 bits)", tok, (unsigned)CAN_EXTD_ID_MASK);
			return -1;
		}
		r.first = (uint32_t)first;
		r.last = (uint32_t)last;
		out[(*count)++] = r;
		continue;
	bad:
		snprintf(err, err_len, "id range '%s' is not HEX or HEX-HEX (prefix e: for 29-bit ids)", tok);
		return -1;
	}
	return 0;
}

static int parse_buses(const char *text, zn_node_config_t *cfg, char *err, size_t err_len)
{
	char buf[ZN_MAX_BUSES * ZN_NAME_MAX];
	char *save = NULL;
	if (snprintf(buf, sizeof(buf), "%s", text) >= (int)sizeof(buf)) {
		snprintf(err, err_len, "CAN bus list too long");
		return -1;
	}
	cfg->bus_count = 0;
	for (char *tok = strtok_r(buf, ",", &save); tok; tok = strtok_r(NULL, ",", &save)) {
		if (cfg->bus_count == ZN_MAX_BUSES) {
			snprintf(err, err_len, "more than %d CAN buses", ZN_MAX_BUSES);
			return -1;
		}
		if (strlen(tok) >= ZN_NAME_MAX) {
			snprintf(err, err_len, "CAN bus name '%s' too long", tok);
			return -1;
		}
		strcpy(cfg->buses[cfg->bus_count++], tok);
	}
	return 0;
}

static int set_string(char *dst, size_t cap, const char *value, const char *what, char *err, size_t err_len)
{
	if (snprintf(dst, cap, "%s", value) >= (int)cap) {
		snprintf(err, err_len, "%s too long (max %zu characters)", what, cap - 1);
		return -1;
	}
	return 0;
}

/* Applies one option; `source` names where it came from for the error line. */
static int apply(zn_node_config_t *cfg, enum opt_id id, const char *value, const char *source, char *err,
		 size_t err_len)
{
	uint32_t u;
	switch (id) {
	case OPT_ENABLED:
		if (parse_bool(value, &cfg->enabled) == 0)
			return 0;
		snprintf(err, err_len, "%s='%s' is not 0 or 1", source, value);
		return -1;
	case OPT_ROUTER:
		return set_string(cfg->router_address, sizeof(cfg->router_address), value, source, err, err_len);
	case OPT_LISTEN:
		return set_string(cfg->listen, sizeof(cfg->listen), value, source, err, err_len);
	case OPT_MODE:
		if (!strcmp(value, "client") || !strcmp(value, "0"))
			cfg->mode = ZN_MODE_CLIENT;
		else if (!strcmp(value, "peer") || !strcmp(value, "1"))
			cfg->mode = ZN_MODE_PEER;
		else if (!strcmp(value, "router") || !strcmp(value, "2"))
			cfg->mode = ZN_MODE_ROUTER;
		else {
			snprintf(err, err_len, "%s='%s' is not client, peer or router (0, 1, 2)", source, value);
			return -1;
		}
		return 0;
	case OPT_PERIOD:
	case OPT_BATCH:
	case OPT_RX_QUEUE:
	case OPT_TX_QUEUE:
	case OPT_RX_PRIORITY:
		if (parse_u32(value, &u) < 0) {
			snprintf(err, err_len, "%s='%s' is not a whole number%s", source, value,
				 id == OPT_PERIOD ? " of milliseconds" : "");
			return -1;
		}
		if (id == OPT_PERIOD)
			cfg->publish_period_ms = u;
		else if (id == OPT_BATCH)
			cfg->batch_max_frames = u;
		else if (id == OPT_RX_QUEUE)
			cfg->rx_queue_frames = u;
		else if (id == OPT_TX_QUEUE)
			cfg->tx_queue_frames = u;
		else
			cfg->rx_qos.priority = u > 255 ? 0 : (uint8_t)u;
		return 0;
	case OPT_PREFIX:
		return set_string(cfg->key_prefix, sizeof(cfg->key_prefix), value, source, err, err_len);
	case OPT_NAME:
		return set_string(cfg->node_name, sizeof(cfg->node_name), value, source, err, err_len);
	case OPT_CAN:
		return parse_buses(value, cfg, err, err_len);
	case OPT_ALLOW:
		return zn_parse_id_ranges(value, cfg->allow, ZN_MAX_ID_RANGES, &cfg->allow_count, err, err_len);
	case OPT_DENY:
		return zn_parse_id_ranges(value, cfg->deny, ZN_MAX_ID_RANGES, &cfg->deny_count, err, err_len);
	case OPT_RX_CONGESTION:
		if (!strcmp(value, "block"))
			cfg->rx_qos.congestion = ZN_CONGESTION_BLOCK;
		else if (!strcmp(value, "drop"))
			cfg->rx_qos.congestion = ZN_CONGESTION_DROP;
		else {
			snprintf(err, err_len, "%s='%s' is not block or drop", source, value);
			return -1;
		}
		return 0;
	case OPT_RX_EXPRESS: {
		bool b;
		if (parse_bool(value, &b) < 0) {
			snprintf(err, err_len, "%s='%s' is not 0 or 1", source, value);
			return -1;
		}
		cfg->rx_qos.express = b;
		return 0;
	}
	case OPT_COMPRESSION:
		if (parse_bool(value, &cfg->compression) == 0)
			return 0;
		snprintf(err, err_len, "%s='%s' is not 0 or 1", source, value);
		return -1;
	case OPT_LOW_LATENCY:
		if (parse_bool(value, &cfg->low_latency) == 0)
			return 0;
		snprintf(err, err_len, "%s='%s' is not 0 or 1", source, value);
		return -1;
	case OPT_ROS2_HUMBLE:
		if (parse_bool(value, &cfg->ros2_humble) == 0)
			return 0;
		snprintf(err, err_len, "%s='%s' is not 0 or 1", source, value);
		return -1;
	case OPT_ROS2_TOPIC:
		return set_string(cfg->ros2_topic, sizeof(cfg->ros2_topic), value, source, err, err_len);
	case OPT_RX_QOS:
		return set_string(cfg->rx_qos_table, sizeof(cfg->rx_qos_table), value, source, err, err_len);
	case OPT_TX_MAX_AGE:
		if (parse_u32(value, &cfg->tx_max_age_ms) == 0)
			return 0;
		snprintf(err, err_len, "%s='%s' is not a whole number of milliseconds", source, value);
		return -1;
	case OPT_ROS2_DOMAIN:
		if (parse_u32(value, &cfg->ros2_domain) == 0)
			return 0;
		snprintf(err, err_len, "%s='%s' is not a number", source, value);
		return -1;
	case OPT_ZENOH_CONFIG:
		return set_string(cfg->zenoh_config_file, sizeof(cfg->zenoh_config_file), value, source, err, err_len);
	case OPT_HELP:
		return 0;
	}
	return -1;
}

int zn_config_from_env_and_args(zn_node_config_t *cfg, int argc, char **argv, char *err, size_t err_len)
{
	struct option longopts[NSPECS + 1];
	zn_node_default_config(cfg);
	for (size_t i = 0; i < NSPECS; i++) {
		const char *value = specs[i].env ? getenv(specs[i].env) : NULL;
		if (value && *value && apply(cfg, specs[i].id, value, specs[i].env, err, err_len) < 0)
			return ZN_CONFIG_ERROR;
		longopts[i] = (struct option){ specs[i].flag, specs[i].arg ? required_argument : no_argument, NULL,
					       (int)specs[i].id };
	}
	longopts[NSPECS] = (struct option){ 0 };
	optind = 1;
	opterr = 0;
	int opt;
	while ((opt = getopt_long(argc, argv, "h", longopts, NULL)) != -1) {
		if (opt == 'h' || opt == OPT_HELP)
			return ZN_CONFIG_HELP;
		if (opt == '?') {
			snprintf(err, err_len, "unknown or incomplete option '%s' (see --help)", argv[optind - 1]);
			return ZN_CONFIG_ERROR;
		}
		char source[64];
		size_t at = 0;
		while (at < NSPECS && specs[at].id != (enum opt_id)opt) /* specs may list options in any order */
			at++;
		snprintf(source, sizeof(source), "--%s", at < NSPECS ? specs[at].flag : "?");
		if (apply(cfg, (enum opt_id)opt, optarg ? optarg : "1", source, err, err_len) < 0)
			return ZN_CONFIG_ERROR;
	}
	if (optind < argc) {
		snprintf(err, err_len, "unexpected argument '%s' (see --help)", argv[optind]);
		return ZN_CONFIG_ERROR;
	}
	if (zn_node_check_config(cfg, err, err_len) != ESP_OK)
		return ZN_CONFIG_ERROR;
	return ZN_CONFIG_OK;
}
