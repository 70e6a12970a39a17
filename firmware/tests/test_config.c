/* test_config.c - configuration from Kconfig defaults, environment and flags:
 * precedence, every option reachable, one clear line for each bad value. */
#include <stdlib.h>
#include <string.h>

#include "check.h"
#include "config_args.h"
#include "zn_config_parse.h"

static void clear_env(void)
{
	const char *vars[] = { "ZENOH_NODE_ENABLED", "ZENOH_ROUTER_ADDRESS", "ZENOH_NODE_MODE", "ZENOH_PUBLISH_PERIOD_MS",
			       "ZENOH_NODE_CAN", "ZENOH_KEY_PREFIX", "ZENOH_RX_CONGESTION", "ZENOH_NODE_ALLOW_IDS",
			       "ZENOH_LOW_LATENCY" };
	for (size_t i = 0; i < sizeof(vars) / sizeof(vars[0]); i++)
		unsetenv(vars[i]);
}

static void test_defaults_are_linux_safe(void)
{
	zn_node_config_t cfg;
	char err[256];
	const char *none[] = { NULL };
	clear_env();
	CHECK(parse_args(&cfg, err, none) == ZN_CONFIG_OK);
	/* never a vehicle network address on the bench */
	CHECK(strcmp(cfg.router_address, "tcp/127.0.0.1:7447") == 0);
	CHECK(cfg.mode == ZN_MODE_CLIENT && cfg.publish_period_ms == 100 && cfg.enabled);
	CHECK(strcmp(cfg.key_prefix, "vehicle/can") == 0 && cfg.bus_count == 1 && !strcmp(cfg.buses[0], "vcan0"));
}

static void test_precedence(void)
{
	zn_node_config_t cfg;
	char err[256];
	clear_env();
	setenv("ZENOH_PUBLISH_PERIOD_MS", "5", 1);
	setenv("ZENOH_NODE_MODE", "peer", 1);
	setenv("ZENOH_ROUTER_ADDRESS", "tcp/127.0.0.1:7000", 1);
	const char *args[] = { "--publish-period-ms", "0", "--can", "vcan0,vcan1", "--rx-congestion", "drop",
			       "--allow-ids", "100-1FF,e:18DA0000-18DAFFFF", "--mode=router", NULL };
	CHECK(parse_args(&cfg, err, args) == ZN_CONFIG_OK);
	CHECK(cfg.publish_period_ms == 0); /* flag beats environment */
	CHECK(cfg.mode == ZN_MODE_ROUTER);
	CHECK(strcmp(cfg.router_address, "tcp/127.0.0.1:7000") == 0); /* environment beats default */
	CHECK(cfg.bus_count == 2 && !strcmp(cfg.buses[1], "vcan1"));
	CHECK(cfg.rx_qos.congestion == ZN_CONGESTION_DROP);
	CHECK(cfg.allow_count == 2 && cfg.allow[1].extended && cfg.allow[1].first == 0x18DA0000);
	clear_env();
	const char *endpoints[] = { "--router", "tls/[::1]:7447, tcp/router.local:7447#iface=lo,", "--deny-ids",
				    "e:1FFFFFFF", "--tx-queue-frames", "4096", NULL };
	CHECK(parse_args(&cfg, err, endpoints) == ZN_CONFIG_OK);
	CHECK(cfg.deny_count == 1 && cfg.deny[0].first == 0x1FFFFFFF && cfg.tx_queue_frames == 4096);
	CHECK(!cfg.low_latency);
	setenv("ZENOH_LOW_LATENCY", "1", 1);
	CHECK(parse_args(&cfg, err, (const char *[]){ "--rx-express", "1", NULL }) == ZN_CONFIG_OK);
	CHECK(cfg.low_latency && cfg.rx_qos.express); /* express asks nothing the transport cannot do */
	unsetenv("ZENOH_LOW_LATENCY");
	CHECK(!cfg.ros2_humble);
	setenv("ZENOH_ROS2_HUMBLE", "1", 1);
	CHECK(parse_args(&cfg, err, (const char *[]){ "--ros2-topic", "/vehicle/can", NULL }) == ZN_CONFIG_OK);
	CHECK(cfg.ros2_humble);
	unsetenv("ZENOH_ROS2_HUMBLE");
	CHECK(parse_args(&cfg, err, (const char *[]){ "--ros2-humble", "0", NULL }) == ZN_CONFIG_OK && !cfg.ros2_humble);
}

static void expect_error(const char *const *args, const char *fragment)
{
	zn_node_config_t cfg;
	char err[256] = "";
	int rc = parse_args(&cfg, err, args);
	CHECK(rc == ZN_CONFIG_ERROR);
	if (!strstr(err, fragment)) {
		fprintf(stderr, "error '%s' does not mention '%s'\n", err, fragment);
		check_failures++;
	}
}

static void test_errors(void)
{
	clear_env();
	expect_error((const char *[]){ "--publish-period-ms", "fast", NULL }, "--publish-period-ms='fast'");
	expect_error((const char *[]){ "--publish-period-ms", "-5", NULL }, "not a whole number");
	expect_error((const char *[]){ "--mode", "server", NULL }, "--mode='server' is not client, peer or router");
	expect_error((const char *[]){ "--rx-congestion", "maybe", NULL }, "block or drop");
	expect_error((const char *[]){ "--allow-ids", "1G0", NULL }, "id range '1G0'");
	expect_error((const char *[]){ "--allow-ids", "200-100", NULL }, "0x200-0x100");
	expect_error((const char *[]){ "--bogus", NULL }, "unknown or incomplete option '--bogus'");
	expect_error((const char *[]){ "stray", NULL }, "unexpected argument 'stray'");
	expect_error((const char *[]){ "--batch-max-frames", "5000", NULL }, "batch max 5000");
	expect_error((const char *[]){ "--rx-priority", "9", NULL }, "priority 9");
	/* issue 19, defect 13: no silent 32-bit truncation (this was taken as 0x7FF) */
	expect_error((const char *[]){ "--deny-ids", "1000007FF", NULL }, "id range '1000007FF' is beyond 0x1FFFFFFF");
	expect_error((const char *[]){ "--allow-ids", "e:0-FFFFFFFFFFFFFFFFF", NULL }, "id range 'e:0-FFFFFFFFFFFFFFFFF'");
	expect_error((const char *[]){ "--allow-ids", "-5", NULL }, "id range '-5'");
	/* a malformed endpoint is a configuration error (one line, exit 2), not an open failure */
	expect_error((const char *[]){ "--router", "tcp/127.0.0.1", NULL }, "router endpoint 'tcp/127.0.0.1' is not");
	expect_error((const char *[]){ "--router", "tcp127.0.0.1:7447", NULL }, "router endpoint 'tcp127.0.0.1:7447'");
	expect_error((const char *[]){ "--router", "tcp/127.0.0.1:7447,tcp/:99999", NULL }, "'tcp/:99999'");
	expect_error((const char *[]){ "--router", "bogus/127.0.0.1:7447", NULL }, "'bogus/127.0.0.1:7447'");
	expect_error((const char *[]){ "--mode", "peer", "--listen", "tcp/0.0.0.0:x", NULL }, "listen endpoint");
	expect_error((const char *[]){ "--tx-queue-frames", "10", NULL }, "tx queue 10 frames");
	/* what the stats' JSON would carry unescaped, or Zenoh refuse at its declaration (exit 1, not 2) */
	expect_error((const char *[]){ "--name", "front\"ecu", NULL }, "node name 'front\"ecu' must be one key chunk");
	expect_error((const char *[]){ "--name", "front\\ecu", NULL }, "node name 'front\\ecu'");
	expect_error((const char *[]){ "--key-prefix", "vehicle//can", NULL }, "key prefix 'vehicle//can'");
	expect_error((const char *[]){ "--key-prefix", "vehicle/c?n", NULL }, "key prefix 'vehicle/c?n'");
	expect_error((const char *[]){ "--key-prefix", "vehicle/$can", NULL }, "key prefix 'vehicle/$can'");
	expect_error((const char *[]){ "--key-prefix", "vehicle/can/", NULL }, "key prefix 'vehicle/can/'");
	/* the low-latency transport has no QoS and no compression: refused, never silently ignored */
	expect_error((const char *[]){ "--low-latency", "fast", NULL }, "--low-latency='fast' is not 0 or 1");
	expect_error((const char *[]){ "--ros2-humble", "humble", NULL }, "--ros2-humble='humble' is not 0 or 1");
	expect_error((const char *[]){ "--low-latency", "1", "--rx-priority", "2", NULL }, "low-latency transport has no QoS");
	expect_error((const char *[]){ "--low-latency", "1", "--rx-congestion", "drop", NULL }, "has no QoS");
	expect_error((const char *[]){ "--low-latency", "1", "--rx-qos", "0x000-0x0FF:realtime", NULL }, "has no QoS");
	expect_error((const char *[]){ "--low-latency", "1", "--compression", "1", NULL }, "does not compress");
	setenv("ZENOH_NODE_ENABLED", "perhaps", 1);
	expect_error((const char *[]){ NULL }, "ZENOH_NODE_ENABLED='perhaps'");
	clear_env();
	zn_node_config_t cfg;
	char err[256];
	CHECK(parse_args(&cfg, err, (const char *[]){ "--help", NULL }) == ZN_CONFIG_HELP);
}

int main(void)
{
	test_defaults_are_linux_safe();
	test_precedence();
	test_errors();
	CHECK_DONE("test_config");
}
