/* zn_ros2.c - the optional ROS 2 output (cfg.ros2_topic): every CAN frame
 * also as can_msgs/msg/Frame the way rmw_zenoh publishes it (data key,
 * liveliness tokens, attachment); docs/viewer.md has the format. */
#include <ctype.h>
#include <inttypes.h>
#include <stdio.h>

#include "zn_internal.h"

static void put_u64_le(uint8_t *p, uint64_t v)
{
	for (int i = 0; i < 8; i++)
		p[i] = (uint8_t)(v >> (8 * i));
}

/* The type hash in keys and tokens: Humble has none, and its rmw_zenoh says so in the hash's place
 * (its subscribers match the key exactly: a RIHS01 hash there and they never see a frame). */
static const char *frame_hash(void)
{
	return zn_node.cfg.ros2_humble ? "TypeHashNotSupported" : ZN_ROS2_FRAME_HASH;
}

/* The ROS 2 topic of one bus and its rmw_zenoh data key. */
esp_err_t zn_ros2_declare_bus(struct bus *b)
{
	const zn_node_config_t *cfg = &zn_node.cfg;
	if (cfg->bus_count == 1)
		snprintf(b->ros_topic, sizeof(b->ros_topic), "%s", cfg->ros2_topic);
	else
		snprintf(b->ros_topic, sizeof(b->ros_topic), "%s/%s", cfg->ros2_topic, b->name);
	/* <domain>/<topic without the leading '/'>/<DDS type>/<type hash> */
	snprintf(b->ros_key, sizeof(b->ros_key), "%" PRIu32 "/%s/%s/%s", cfg->ros2_domain, b->ros_topic + 1,
		 ZN_ROS2_FRAME_TYPE, frame_hash());
	if (zn_declare_publisher(zn_node.session, b->ros_key, &cfg->rx_qos, &b->ros_pub) != 0) {
		zn_log("E", "cannot declare the ROS 2 publisher %s", b->ros_key);
		return ESP_FAIL;
	}
	return ESP_OK;
}

/* One can_msgs/msg/Frame sample per CAN frame, with rmw_zenoh's attachment: int64
 * sequence number, int64 source time (ns), the publisher's GID (length 16, bytes). */
void zn_ros2_publish(struct bus *b, const struct rx_entry *frames, size_t n)
{
	uint8_t cdr[64 + ZN_NAME_MAX];
	uint8_t att[8 + 8 + 1 + 16];
	for (size_t i = 0; i < n; i++) {
		int len = zn_ros2_encode_can_frame(&frames[i].msg, frames[i].rx_time_ns, b->name, cdr, sizeof(cdr));
		if (len < 0)
			continue;
		put_u64_le(att, ++b->ros_seq);
		put_u64_le(att + 8, (uint64_t)frames[i].rx_time_ns);
		att[16] = 16;
		for (int g = 0; g < 16; g++) /* a GID unique to this bus's publisher within the node */
			att[17 + g] = (uint8_t)(zn_node.gid_seed[g] ^ (g == 15 ? b->index : 0));
		zn_put(b->ros_pub, cdr, (size_t)len, att, sizeof(att));
	}
}

/* rmw_zenoh's liveliness tokens: the node, and one publisher per bus, so ROS 2 tools
 * list them and subscribers match (docs/viewer.md has the format). */
esp_err_t zn_ros2_declare_tokens(const char *zid)
{
	const zn_node_config_t *cfg = &zn_node.cfg;
	char ros_node[ZN_NAME_MAX], key[2 * ZN_KEY_MAX], topic[ZN_KEY_MAX];
	snprintf(ros_node, sizeof(ros_node), "%s", cfg->node_name);
	for (char *c = ros_node; *c; c++)
		if (!isalnum((unsigned char)*c))
			*c = '_'; /* ROS node names: letters, digits, '_' */
	for (int g = 0; g < 16; g++) {
		unsigned v = 0;
		sscanf(zid + 2 * g, "%2x", &v);
		zn_node.gid_seed[g] = (uint8_t)v;
	}
	int n = snprintf(key, sizeof(key), "@ros2_lv/%" PRIu32 "/%s/0/0/NN/%%/%%/%s", cfg->ros2_domain, zid, ros_node);
	if (n < 0 || (size_t)n >= sizeof(key) || zn_declare_token(zn_node.session, key, &zn_node.ros_node_token) != 0)
		return ESP_FAIL;
	for (size_t i = 0; i < cfg->bus_count; i++) {
		struct bus *b = &zn_node.buses[i];
		snprintf(topic, sizeof(topic), "%s", b->ros_topic);
		for (char *c = topic; *c; c++)
			if (*c == '/')
				*c = '%';
		n = snprintf(key, sizeof(key), "@ros2_lv/%" PRIu32 "/%s/0/%zu/MP/%%/%%/%s/%s/%s/%s/::,10:,:,:,,",
			     cfg->ros2_domain, zid, i + 1, ros_node, topic, ZN_ROS2_FRAME_TYPE, frame_hash());
		if (n < 0 || (size_t)n >= sizeof(key)) { /* never a truncated key */
			zn_log("E", "ROS 2: the liveliness token of %s would exceed %zu bytes", b->ros_topic, sizeof(key));
			return ESP_ERR_INVALID_SIZE;
		}
		if (zn_declare_token(zn_node.session, key, &b->ros_token) != 0)
			return ESP_FAIL;
		zn_log("I", "ROS 2: %s as can_msgs/msg/Frame on %s", b->ros_topic, b->ros_key);
	}
	return ESP_OK;
}
