/* test_qos.c - the CAN -> Zenoh QoS table: parsing and its errors (through the
 * option table, flag and environment), one publisher per class with its QoS,
 * frames routed to their class's publisher, the highest class published first,
 * sequence numbers per bus without gaps across classes, a queue per class. */
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "check.h"
#include "le64.h"
#include "config_args.h"
#include "zn_config_parse.h"
#include "zn_mock.h"
#include "zn_node.h"
#include "zn_qos.h"
#include "zn_wire.h"

#define WAIT_MS 5000
#define EXAMPLE "0x000-0x0FF:realtime,express;0x100-0x7FF:data,best-effort"

static const zn_qos_t base = { .priority = 5, .congestion = ZN_CONGESTION_BLOCK, .express = 0, .best_effort = 0 };

static can_message_t frame(uint32_t id, int extd, uint8_t fill)
{
	can_message_t m;
	memset(&m, 0, sizeof(m));
	m.identifier = id;
	m.extd = (uint32_t)extd;
	m.data_length_code = 1;
	m.data[0] = fill;
	return m;
}

static int qos_is(const zn_qos_t *q, uint8_t priority, zn_congestion_t congestion, uint8_t express, uint8_t best_effort)
{
	return q->priority == priority && q->congestion == congestion && q->express == express &&
	       q->best_effort == best_effort;
}

static void test_parse(void)
{
	zn_qos_table_t t;
	char err[256] = "";
	CHECK(zn_qos_parse(EXAMPLE, &base, &t, err, sizeof(err)) == 0);
	/* classes by priority: realtime, then the two data ones in table order, the default last */
	CHECK(t.class_count == 3 && t.rule_count == 2 && t.default_class == 2);
	CHECK(qos_is(&t.classes[0], 1, ZN_CONGESTION_BLOCK, 1, 0));
	CHECK(qos_is(&t.classes[1], 5, ZN_CONGESTION_BLOCK, 0, 1));
	CHECK(qos_is(&t.classes[2], 5, ZN_CONGESTION_BLOCK, 0, 0));
	can_message_t hi = frame(0x0FF, 0, 0), lo = frame(0x100, 0, 0), ext = frame(0x050, 1, 0);
	CHECK(zn_qos_class_of(&t, &hi) == 0 && zn_qos_class_of(&t, &lo) == 1);
	CHECK(zn_qos_class_of(&t, &ext) == 2); /* a 29-bit 0x050 is not the 11-bit 0x050 */

	/* equal QoS share a class; a rule equal to the default is the default class */
	CHECK(zn_qos_parse(" 0-F : realtime ; 10-1F:realtime;e:18DA0000-18DAFFFF:background,drop;200-2FF:data", &base,
			   &t, err, sizeof(err)) == 0);
	CHECK(t.class_count == 3 && t.rule_count == 4);
	CHECK(t.rules[0].cls == 0 && t.rules[1].cls == 0 && t.rules[3].cls == t.default_class && t.default_class == 1);
	CHECK(qos_is(&t.classes[2], 7, ZN_CONGESTION_DROP, 0, 0) && t.rules[2].extended && t.rules[2].cls == 2);
	can_message_t diag = frame(0x18DAF110, 1, 0);
	CHECK(zn_qos_class_of(&t, &diag) == 2);

	/* no table: one class, the default */
	CHECK(zn_qos_parse("", &base, &t, err, sizeof(err)) == 0 && t.class_count == 1 && t.default_class == 0);
	CHECK(qos_is(&t.classes[0], 5, ZN_CONGESTION_BLOCK, 0, 0));
	/* a rule starts from the default it is given (--rx-congestion drop here) */
	zn_qos_t dropping = base;
	dropping.congestion = ZN_CONGESTION_DROP;
	CHECK(zn_qos_parse("e:0-1FFFFFFF:reliable,block,interactive-low", &dropping, &t, err, sizeof(err)) == 0);
	CHECK(qos_is(&t.classes[0], 3, ZN_CONGESTION_BLOCK, 0, 0) && qos_is(&t.classes[1], 5, ZN_CONGESTION_DROP, 0, 0));
	char words[64];
	zn_qos_describe(&t.classes[0], words, sizeof(words));
	CHECK(strcmp(words, "interactive-low,block,reliable") == 0);
}

/* tests/data/rx_qos_vectors.txt, beside the wire vectors: the bench's parser holds to the same lines. */
static void test_vectors(void)
{
	char path[512];
	snprintf(path, sizeof(path), "%s", WIRE_VECTORS);
	char *slash = strrchr(path, '/');
	snprintf(slash ? slash + 1 : path, sizeof(path) - (size_t)(slash ? slash + 1 - path : 0), "rx_qos_vectors.txt");
	FILE *f = fopen(path, "r");
	CHECK(f != NULL);
	if (!f)
		return;
	char line[1024];
	int lines = 0;
	while (fgets(line, sizeof(line), f)) {
		line[strcspn(line, "\n")] = '\0';
		if (line[0] == '#' || !line[0])
			continue;
		char *field[4] = { line, NULL, NULL, NULL };
		for (int i = 1; i < 4 && field[i - 1]; i++) { /* empty fields count: no strtok */
			char *tab = strchr(field[i - 1], '\t');
			if (tab) {
				*tab = '\0';
				field[i] = tab + 1;
			}
		}
		zn_qos_table_t t;
		char err[256] = "";
		int rc = field[1] ? zn_qos_parse(field[1], &base, &t, err, sizeof(err)) : -2;
		lines++;
		if (!strcmp(field[0], "err")) {
			if (rc != -1 || !field[2] || !strstr(err, field[2]) || strncmp(err, "rx QoS table: ", 14) != 0) {
				fprintf(stderr, "%s: '%s' gave '%s', expected an error with '%s'\n", path, field[1], err,
					field[2] ? field[2] : "?");
				check_failures++;
			}
			continue;
		}
		if (rc != 0 || !field[2] || !field[3]) {
			fprintf(stderr, "%s: '%s' refused: %s\n", path, field[1] ? field[1] : "", err);
			check_failures++;
			continue;
		}
		char classes[512] = "";
		for (size_t c = 0; c < t.class_count; c++) {
			char one[64];
			zn_qos_describe(&t.classes[c], one, sizeof(one));
			snprintf(classes + strlen(classes), sizeof(classes) - strlen(classes), "%s%s", c ? ";" : "", one);
		}
		if (strcmp(classes, field[2]) != 0) {
			fprintf(stderr, "%s: '%s' has classes '%s', expected '%s'\n", path, field[1], classes, field[2]);
			check_failures++;
		}
		for (char *probe = strtok(field[3], ";"); probe; probe = strtok(NULL, ";")) {
			int extd = !strncmp(probe, "e:", 2);
			char *eq = strchr(probe, '=');
			CHECK(eq != NULL);
			if (!eq)
				break;
			can_message_t m = frame((uint32_t)strtoul(probe + (extd ? 2 : 0), NULL, 16), extd, 0);
			if (zn_qos_class_of(&t, &m) != (uint8_t)atoi(eq + 1)) {
				fprintf(stderr, "%s: '%s': %s is in class %u\n", path, field[1], probe, zn_qos_class_of(&t, &m));
				check_failures++;
			}
		}
	}
	fclose(f);
	CHECK(lines >= 20);
}

static void expect_error(const char *table, const char *fragment)
{
	zn_node_config_t cfg;
	char err[256] = "";
	CHECK(parse_args(&cfg, err, (const char *[]){ "--rx-qos", table, NULL }) == ZN_CONFIG_ERROR);
	if (!strstr(err, fragment) || strchr(err, '\n') || strncmp(err, "rx QoS table: ", 14) != 0) {
		fprintf(stderr, "--rx-qos '%s': error '%s' does not mention '%s' in one line\n", table, err, fragment);
		check_failures++;
	}
}

static void test_option_and_errors(void)
{
	zn_node_config_t cfg;
	char err[256];
	unsetenv("ZENOH_RX_QOS");
	CHECK(parse_args(&cfg, err, (const char *[]){ NULL }) == ZN_CONFIG_OK && cfg.rx_qos_table[0] == '\0');
	setenv("ZENOH_RX_QOS", "0-FF:realtime", 1);
	CHECK(parse_args(&cfg, err, (const char *[]){ NULL }) == ZN_CONFIG_OK && !strcmp(cfg.rx_qos_table, "0-FF:realtime"));
	CHECK(parse_args(&cfg, err, (const char *[]){ "--rx-qos", EXAMPLE, NULL }) == ZN_CONFIG_OK &&
	      !strcmp(cfg.rx_qos_table, EXAMPLE)); /* the flag beats the environment */
	setenv("ZENOH_RX_QOS", "0-FF:fast", 1);
	CHECK(parse_args(&cfg, err, (const char *[]){ NULL }) == ZN_CONFIG_ERROR && strstr(err, "'fast'"));
	unsetenv("ZENOH_RX_QOS");

	expect_error("0x000-0x0FF:realtime;0x080-0x100:data", "0x80-0x100 overlaps 0x0-0xFF");
	expect_error("e:100-200:realtime;e:1FF:data", "e:0x1FF-0x1FF overlaps e:0x100-0x200");
	expect_error("0-FF:fast", "'fast' is not a priority (realtime, interactive-high");
	expect_error("0-FF:realtime,urgent", "'urgent' is not a priority");
	expect_error("0x800:realtime", "id range '0x800' is beyond 0x7FF (11 bits; prefix e: for 29-bit ids)");
	expect_error("0x100-0x1FFFFFFF:data", "beyond 0x7FF");
	expect_error("e:0-0x20000000:background", "id range 'e:0-0x20000000' is beyond 0x1FFFFFFF (29 bits)");
	expect_error("e:100000000:data", "is not HEX or HEX-HEX"); /* 9 digits: never cut to 32 bits */
	expect_error("0x1G:realtime", "id range '0x1G' is not HEX");
	expect_error("-5:realtime", "id range '-5' is not HEX");
	expect_error("200-100:data", "id range '200-100' is empty");
	expect_error("0-FF:drop,block", "'block' names the congestion control (drop or block) a second time");
	expect_error("0-FF:realtime,data", "'data' names the priority a second time");
	expect_error("0-FF:best-effort,reliable", "reliability");
	expect_error("0-FF", "rule '0-FF' is not RANGE:QOS");
	expect_error("0-FF:", "rule '0-FF:' names no QoS");
	expect_error("0-FF:realtime;", "an empty rule after the last ';'");
	expect_error("0-FF:realtime;;100-1FF:data", "an empty rule");
	expect_error("0-FF:realtime,,express", "an empty QoS item");
	expect_error("0-F:realtime;10-1F:interactive-high;20-2F:interactive-low;30-3F:data-high;40-4F:data-low;"
		     "50-5F:background;60-6F:realtime,express;70-7F:realtime,drop",
		     "more than 8 distinct QoS classes");
	expect_error("0:data;1:data;2:data;3:data;4:data;5:data;6:data;7:data;8:data;9:data;A:data;B:data;C:data;"
		     "D:data;E:data;F:data;10:data",
		     "more than 16 rules");
	/* eight classes, the default included, are fine */
	CHECK(parse_args(&cfg, err, (const char *[]){ "--rx-qos", "0-F:realtime;10-1F:interactive-high;20-2F:interactive-low;"
						      "30-3F:data-high;40-4F:data-low;50-5F:background;60-6F:realtime,express", NULL }) == ZN_CONFIG_OK);
}

static zn_node_config_t node_config(uint32_t period_ms, const char *table)
{
	zn_node_config_t cfg;
	zn_node_default_config(&cfg);
	cfg.publish_period_ms = period_ms;
	cfg.rx_queue_frames = 1024;
	snprintf(cfg.rx_qos_table, sizeof(cfg.rx_qos_table), "%s", table);
	return cfg;
}

static int stats_soon_has(const char *needle)
{
	char buf[16384];
	size_t n = 0;
	for (int waited_ms = 0; waited_ms < WAIT_MS; waited_ms++) {
		n = mock_zenoh_query("vehicle/can/bridges/zenoh-node/stats", buf, sizeof(buf));
		if (n > 0 && strstr(buf, needle))
			return 1;
		nanosleep(&(struct timespec){ .tv_nsec = 1000000 }, NULL);
	}
	fprintf(stderr, "stats lack '%s': %.*s\n", needle, (int)n, buf);
	return 0;
}

/* No table: one publisher with rx_qos, as before the table existed. */
static void test_default_one_publisher(void)
{
	mock_reset();
	zn_node_config_t cfg = node_config(0, "");
	cfg.rx_qos.priority = 4;
	CHECK(zn_node_init(&cfg) == ESP_OK);
	CHECK(mock_zenoh_publisher_count() == 1);
	CHECK(!strcmp(mock_zenoh_publisher(0)->key, "vehicle/can/rx"));
	CHECK(qos_is(&mock_zenoh_publisher(0)->qos, 4, ZN_CONGESTION_BLOCK, 0, 0));
	char buf[16384];
	size_t len = zn_node_stats_json(buf, sizeof(buf));
	CHECK(len > 0 && len < sizeof(buf) && !strstr(buf, "rx_classes"));
	/* too small: nothing but "", and the length it needs (snprintf's contract; uptime_ms may
	 * gain a digit meanwhile) */
	char small[64];
	size_t need = zn_node_stats_json(small, sizeof(small));
	CHECK(need >= len && need <= len + 1 && small[0] == '\0');
	need = zn_node_stats_json(small, 0);
	CHECK(need >= len && need <= len + 1);
	zn_node_stop();
}

/* Every frame through its class's publisher on the one key; sequence numbers gap-free
 * across classes, in order within each. */
static void test_routing(void)
{
	mock_reset();
	zn_node_config_t cfg = node_config(0, EXAMPLE);
	CHECK(zn_node_init(&cfg) == ESP_OK);
	CHECK(mock_zenoh_publisher_count() == 3);
	for (size_t i = 0; i < 3 && i < mock_zenoh_publisher_count(); i++)
		CHECK(!strcmp(mock_zenoh_publisher(i)->key, "vehicle/can/rx"));
	CHECK(qos_is(&mock_zenoh_publisher(0)->qos, 1, ZN_CONGESTION_BLOCK, 1, 0));
	CHECK(qos_is(&mock_zenoh_publisher(1)->qos, 5, ZN_CONGESTION_BLOCK, 0, 1));
	CHECK(qos_is(&mock_zenoh_publisher(2)->qos, 5, ZN_CONGESTION_BLOCK, 0, 0));
	const struct { uint32_t id; int extd; int publisher; } in[] = {
		{ 0x300, 0, 1 }, { 0x010, 0, 0 }, { 0x301, 0, 1 }, { 0x010, 1, 2 }, { 0x0FF, 0, 0 }, { 0x7FF, 0, 1 },
	};
	size_t n = sizeof(in) / sizeof(in[0]);
	for (size_t i = 0; i < n; i++) {
		can_message_t m = frame(in[i].id, in[i].extd, (uint8_t)i);
		mock_can_inject("vcan0", &m, 100 + (int64_t)i);
	}
	CHECK(mock_zenoh_wait_puts(n, WAIT_MS) == n);
	int seen[16] = { 0 };
	int64_t last_seq[3] = { -1, -1, -1 };
	for (size_t k = 0; k < mock_zenoh_put_count(); k++) {
		const struct mock_put *p = mock_zenoh_put(k);
		CHECK(!strcmp(p->key, "vehicle/can/rx") && p->len == 16);
		uint64_t seq = le64(p->attachment + 4);
		CHECK(seq < n);
		if (seq >= n)
			continue;
		seen[seq]++;
		CHECK(p->payload[8] == seq);		     /* the frame is the seq-th one read */
		CHECK(le64(p->attachment + 12) == 100 + seq); /* with its own stamp */
		CHECK(p->publisher == in[seq].publisher);
		CHECK(p->publisher >= 0 && p->publisher < 3 && (int64_t)seq > last_seq[p->publisher]);
		if (p->publisher >= 0 && p->publisher < 3)
			last_seq[p->publisher] = (int64_t)seq;
	}
	for (size_t i = 0; i < n; i++)
		CHECK(seen[i] == 1);
	CHECK(stats_soon_has("\"published_frames\": 6"));
	CHECK(stats_soon_has("\"rx_classes\": [{\"qos\": \"realtime,express,block,reliable\", \"published_frames\": 2, "
			     "\"rx_queue_drops\": 0}, {\"qos\": \"data,block,best-effort\", \"published_frames\": 3, "
			     "\"rx_queue_drops\": 0}, {\"qos\": \"data,block,reliable\", \"published_frames\": 1, "
			     "\"rx_queue_drops\": 0}]"));
	zn_node_stop();
}

static void wait_read(const char *count)
{
	char needle[64];
	snprintf(needle, sizeof(needle), "\"can_rx_frames\": %s,", count);
	CHECK(stats_soon_has(needle));
}

/* A batch is split by class and the highest class published first; within a class, samples
 * hold consecutive sequence numbers only (the attachment numbers consecutive frames). */
static void test_high_class_first(void)
{
	mock_reset();
	zn_node_config_t cfg = node_config(60000, EXAMPLE); /* a period that never ends: stop flushes */
	CHECK(zn_node_init(&cfg) == ESP_OK);
	const uint32_t ids[] = { 0x300, 0x301, 0x010, 0x302, 0x011 }; /* seq 0..4: low, low, high, low, high */
	for (size_t i = 0; i < 5; i++) {
		can_message_t m = frame(ids[i], 0, (uint8_t)i);
		mock_can_inject("vcan0", &m, 1);
	}
	wait_read("5");
	CHECK(mock_zenoh_put_count() == 0);
	zn_node_stop();
	CHECK(mock_zenoh_put_count() == 4);
	const struct { int publisher; uint64_t seq; uint8_t count; } expect[] = {
		{ 0, 2, 1 }, { 0, 4, 1 }, { 1, 0, 2 }, { 1, 3, 1 },
	};
	for (size_t k = 0; k < 4 && k < mock_zenoh_put_count(); k++) {
		const struct mock_put *p = mock_zenoh_put(k);
		CHECK(p->publisher == expect[k].publisher);
		CHECK(le64(p->attachment + 4) == expect[k].seq && p->attachment[2] == expect[k].count);
		CHECK(p->len == 16u * expect[k].count);
		for (size_t f = 0; f < expect[k].count; f++)
			CHECK(p->payload[16 * f + 8] == expect[k].seq + f);
	}
}

/* A flood in one class fills that class's queue only: a frame of another class still gets in. */
static void test_queue_per_class(void)
{
	mock_reset();
	zn_node_config_t cfg = node_config(60000, EXAMPLE);
	cfg.rx_queue_frames = 16;
	CHECK(zn_node_init(&cfg) == ESP_OK);
	for (int i = 0; i < 20; i++) {
		can_message_t m = frame(0x400, 0, (uint8_t)i);
		mock_can_inject("vcan0", &m, 1);
	}
	can_message_t safety = frame(0x001, 0, 0xEE);
	mock_can_inject("vcan0", &safety, 2);
	wait_read("21");
	CHECK(stats_soon_has("\"rx_queue_drops\": 4,"));
	CHECK(stats_soon_has("\"published_frames\": 0, \"rx_queue_drops\": 4}")); /* the flood's class */
	zn_node_stop();
	CHECK(mock_zenoh_put_count() == 2);
	CHECK(mock_zenoh_put(0) && mock_zenoh_put(0)->publisher == 0 && mock_zenoh_put(0)->payload[8] == 0xEE);
	CHECK(le64(mock_zenoh_put(0)->attachment + 4) == 20);
	CHECK(mock_zenoh_put(1) && mock_zenoh_put(1)->publisher == 1 && mock_zenoh_put(1)->len == 16 * 16);
}

/* An invalid table never reaches the ports: init refuses it as the configuration check does. */
static void test_init_refuses(void)
{
	mock_reset();
	zn_node_config_t cfg = node_config(0, "0-FF:realtime;80:data");
	char err[256];
	CHECK(zn_node_check_config(&cfg, err, sizeof(err)) == ESP_ERR_INVALID_ARG && strstr(err, "overlaps"));
	CHECK(zn_node_init(&cfg) == ESP_ERR_INVALID_ARG);
	CHECK(mock_zenoh_publisher_count() == 0);
}

int main(void)
{
	test_parse();
	test_vectors();
	test_option_and_errors();
	test_default_one_publisher();
	test_routing();
	test_high_class_first();
	test_queue_per_class();
	test_init_refuses();
	CHECK_DONE("test_qos");
}
