/* zn_node.h - zenoh-node: bridges CAN 2.0 frames and Zenoh pub/sub.
 *
 * CAN -> Zenoh: frames received on each bus are published on <prefix>/rx
 * (one bus) or <prefix>/<bus>/rx (several), one frame per sample or, with a
 * publish period, batches of N x 16 bytes. Zenoh -> CAN: samples on .../tx
 * are validated frame by frame and transmitted; anything invalid is refused
 * whole and counted by reason. Every sample carries an attachment with a
 * sequence number and CAN receive timestamps (zn_wire.h; docs/bridge.md). */
#ifndef ZN_NODE_H
#define ZN_NODE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "driver/can.h"
#include "esp_err.h"
#include "zn_port_zenoh.h"

#define ZN_MAX_BUSES 8
#define ZN_MAX_ID_RANGES 16
#define ZN_NAME_MAX 64
#define ZN_KEY_MAX 256
#define ZN_ENDPOINTS_MAX 512
#define ZN_BATCH_MAX_FRAMES 1024 /* 16 KiB payload */
#define ZN_QOS_TABLE_MAX 512	 /* the text of the CAN -> Zenoh QoS table */
/* The largest Zenoh message the node needs to receive: a command of
 * ZN_BATCH_MAX_FRAMES frames with its attachment, plus room for Zenoh's own
 * framing and the key. The Zenoh port caps reassembly at this, so no
 * publisher can make the node buffer more (Zenoh's default is 1 GiB). */
#define ZN_RX_MESSAGE_MAX (ZN_BATCH_MAX_FRAMES * 16 + 12 + ZN_BATCH_MAX_FRAMES * 8 + 8192)

typedef struct {
	uint32_t first, last; /* inclusive; flags not included: compare raw identifiers */
	bool extended;	      /* range applies to 29-bit (true) or 11-bit (false) ids */
} zn_id_range_t;

typedef struct {
	bool enabled;				 /* CONFIG_ZENOH_NODE_ENABLED */
	char node_name[ZN_NAME_MAX];		 /* liveliness token and stats name */
	char router_address[ZN_ENDPOINTS_MAX];	 /* CONFIG_ZENOH_ROUTER_ADDRESS; connect endpoints */
	char listen[ZN_ENDPOINTS_MAX];		 /* listen endpoints (peer / router mode) */
	zn_mode_t mode;				 /* CONFIG_ZENOH_NODE_MODE */
	uint32_t publish_period_ms;		 /* CONFIG_ZENOH_PUBLISH_PERIOD_MS; 0 = each frame at once */
	uint32_t batch_max_frames;		 /* flush a batch early when it holds this many */
	char key_prefix[ZN_NAME_MAX];		 /* "vehicle/can" */
	char buses[ZN_MAX_BUSES][ZN_NAME_MAX];	 /* CAN bus names */
	size_t bus_count;
	zn_id_range_t allow[ZN_MAX_ID_RANGES]; /* CAN -> Zenoh: only these ids (none = all) */
	size_t allow_count;
	zn_id_range_t deny[ZN_MAX_ID_RANGES]; /* ... never these (deny wins) */
	size_t deny_count;
	zn_qos_t rx_qos;		       /* CAN -> Zenoh (telemetry) */
	char rx_qos_table[ZN_QOS_TABLE_MAX]; /* CONFIG_ZENOH_RX_QOS: QoS per CAN id range over rx_qos (zn_qos.h; "" = none) */
	uint32_t rx_queue_frames;	       /* frames buffered between CAN reader and publisher */
	uint32_t tx_queue_frames;	       /* CONFIG_ZENOH_TX_QUEUE_FRAMES: command frames waiting for CAN */
	uint32_t tx_max_age_ms; /* CONFIG_ZENOH_TX_MAX_AGE_MS: refuse commands older than this (0 = off) */
	char zenoh_config_file[ZN_ENDPOINTS_MAX]; /* optional JSON5 (TLS, auth) */
	bool compression;			  /* CONFIG_ZENOH_COMPRESSION: compress the Zenoh transport */
	bool low_latency; /* CONFIG_ZENOH_LOW_LATENCY: Zenoh's low-latency transport (no QoS) */
	char ros2_topic[ZN_NAME_MAX]; /* CONFIG_ZENOH_ROS2_TOPIC: also publish can_msgs/msg/Frame here ("" = off) */
	uint32_t ros2_domain;	      /* CONFIG_ZENOH_ROS2_DOMAIN: ROS_DOMAIN_ID of that topic */
	bool ros2_humble;	      /* CONFIG_ZENOH_ROS2_HUMBLE: Humble's keys (TypeHashNotSupported, no RIHS01 hash) */
} zn_node_config_t;

/* Fills cfg with the Kconfig defaults (CONFIG_* from sdkconfig). */
void zn_node_default_config(zn_node_config_t *cfg);

/* Validates cfg; on error writes one line explaining it into err. */
esp_err_t zn_node_check_config(const zn_node_config_t *cfg, char *err, size_t err_len);

/* Opens the Zenoh session, declares publishers, subscribers, liveliness token
 * and stats queryable, opens the CAN buses and starts the bridge threads. */
esp_err_t zn_node_init(const zn_node_config_t *cfg);

/* Queues a frame received on bus `bus` at rx_time_ns for publication. */
esp_err_t zn_node_submit(size_t bus, const can_message_t *msg, int64_t rx_time_ns);

/* Does the CAN -> Zenoh id filter let this frame through? */
bool zn_node_id_allowed(const zn_node_config_t *cfg, const can_message_t *msg);

/* Writes the counters as one JSON object and returns its length. A length of cap
 * or more means it did not fit: buf holds "" and length + 1 bytes are needed
 * (snprintf's contract; 8 buses with 8 QoS classes each take 12 to 18 KiB). */
size_t zn_node_stats_json(char *buf, size_t cap);

/* Flushes pending batches, undeclares everything, closes the session. */
void zn_node_stop(void);

#endif
