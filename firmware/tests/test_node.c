/* test_node.c - zenoh-node on mock ports: both directions, batching,
 * filters, refusals by reason, stats, liveliness token, flush on stop,
 * CAN reads in bursts. */
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "check.h"
#include "le64.h"
#include "zn_node.h"
#include "zn_wire.h"
#include "zn_mock.h"
#include "published.h"

#define WAIT_MS 5000

static can_message_t frame(uint32_t id, int extd, int rtr, uint8_t dlc, uint8_t fill)
{
	can_message_t m;
	memset(&m, 0, sizeof(m));
	m.identifier = id;
	m.extd = (uint32_t)extd;
	m.rtr = (uint32_t)rtr;
	m.data_length_code = dlc;
	if (!rtr)
		memset(m.data, fill, dlc);
	return m;
}

static zn_node_config_t base_config(uint32_t period_ms)
{
	zn_node_config_t cfg;
	zn_node_default_config(&cfg);
	cfg.publish_period_ms = period_ms;
	cfg.rx_queue_frames = 1024;
	return cfg;
}

static int stats_has(const char *needle)
{
	char buf[8192];
	size_t n = mock_zenoh_query("vehicle/can/bridges/zenoh-node/stats", buf, sizeof(buf));
	if (n == 0 || !strstr(buf, needle)) {
		fprintf(stderr, "stats lack '%s': %.*s\n", needle, (int)n, buf);
		return 0;
	}
	return 1;
}

/* Counters are updated just after the put the mock records returns: poll them (bounded). */
static int stats_soon_has(const char *needle)
{
	char buf[8192];
	for (int waited_ms = 0; waited_ms < WAIT_MS; waited_ms++) {
		size_t n = mock_zenoh_query("vehicle/can/bridges/zenoh-node/stats", buf, sizeof(buf));
		if (n > 0 && strstr(buf, needle))
			return 1;
		nanosleep(&(struct timespec){ .tv_nsec = 1000000 }, NULL);
	}
	return stats_has(needle); /* prints what the stats say */
}

static void test_immediate_mode(void)
{
	mock_reset();
	zn_node_config_t cfg = base_config(0);
	CHECK(zn_node_init(&cfg) == ESP_OK);
	CHECK(mock_zenoh_has_token("vehicle/can/bridges/zenoh-node/vcan0/client"));
	can_message_t in[3] = { frame(0x123, 0, 0, 2, 0xAB), frame(0x18DAF110, 1, 0, 8, 0x11), frame(0x7FF, 0, 1, 4, 0) };
	for (int i = 0; i < 3; i++)
		mock_can_inject("vcan0", &in[i], 1000 + i);
	CHECK(mock_zenoh_wait_puts(3, WAIT_MS) == 3);
	for (size_t i = 0; i < 3; i++) {
		const struct mock_put *p = mock_zenoh_put(i);
		uint8_t expect[16];
		CHECK(strcmp(p->key, "vehicle/can/rx") == 0);
		CHECK(zn_wire_encode(&in[i], expect, 16) == 16);
		CHECK(p->len == 16 && memcmp(p->payload, expect, 16) == 0);
		CHECK(p->attachment_len == ZN_ATTACHMENT_HEADER + 8);
		CHECK(p->attachment[0] == ZN_ATTACHMENT_VERSION && p->attachment[2] == 1 && p->attachment[3] == 0);
		CHECK(le64(p->attachment + 4) == i);
		CHECK(le64(p->attachment + 12) == 1000 + i);
	}
	CHECK(stats_soon_has("\"published_frames\": 3"));
	zn_node_stop();
	CHECK(!mock_zenoh_has_token("vehicle/can/bridges/zenoh-node/vcan0/client"));
}

static void test_filters(void)
{
	mock_reset();
	zn_node_config_t cfg = base_config(0);
	cfg.allow[0] = (zn_id_range_t){ 0x100, 0x1FF, false };
	cfg.allow[1] = (zn_id_range_t){ 0x18DA0000, 0x18DAFFFF, true };
	cfg.allow_count = 2;
	cfg.deny[0] = (zn_id_range_t){ 0x150, 0x150, false };
	cfg.deny_count = 1;
	CHECK(zn_node_init(&cfg) == ESP_OK);
	uint32_t ids[] = { 0x050, 0x100, 0x150, 0x1FF, 0x200 };
	for (size_t i = 0; i < 5; i++) {
		can_message_t m = frame(ids[i], 0, 0, 1, 1);
		mock_can_inject("vcan0", &m, 1);
	}
	can_message_t ext_in = frame(0x18DA0001, 1, 0, 1, 1), ext_out = frame(0x100, 1, 0, 1, 1);
	mock_can_inject("vcan0", &ext_out, 1); /* a 29-bit 0x100 is not the 11-bit 0x100 */
	mock_can_inject("vcan0", &ext_in, 1);
	CHECK(mock_zenoh_wait_puts(3, WAIT_MS) == 3);
	CHECK(mock_zenoh_put(0)->payload[0] == 0x00 && mock_zenoh_put(0)->payload[1] == 0x01);
	CHECK(mock_zenoh_put(1)->payload[0] == 0xFF);
	CHECK(mock_zenoh_put(2)->payload[3] == 0x18);
	CHECK(stats_soon_has("\"filtered\": 4"));
	zn_node_stop();
}

static void test_batching(void)
{
	mock_reset();
	zn_node_config_t cfg = base_config(20);
	cfg.batch_max_frames = 4;
	CHECK(zn_node_init(&cfg) == ESP_OK);
	for (int i = 0; i < 10; i++) {
		can_message_t m = frame((uint32_t)i, 0, 0, 1, (uint8_t)i);
		mock_can_inject("vcan0", &m, 500 + i);
	}
	size_t frames = 0, puts = 0;
	while (frames < 10 && mock_zenoh_wait_puts(puts + 1, WAIT_MS) > puts) {
		const struct mock_put *p = mock_zenoh_put(puts++);
		size_t n = p->len / 16;
		CHECK(p->len % 16 == 0 && n >= 1 && n <= 4);
		CHECK(p->attachment_len == ZN_ATTACHMENT_HEADER + 8 * n);
		CHECK(p->attachment[2] == n);
		CHECK(le64(p->attachment + 4) == frames); /* sequence continues across samples */
		for (size_t k = 0; k < n; k++) {
			CHECK(p->payload[16 * k] == frames + k);
			CHECK(le64(p->attachment + 12 + 8 * k) == 500 + frames + k);
		}
		frames += n;
	}
	CHECK(frames == 10);
	zn_node_stop();
}

static void test_flush_on_stop(void)
{
	mock_reset();
	zn_node_config_t cfg = base_config(60000); /* a period that never ends during the test */
	CHECK(zn_node_init(&cfg) == ESP_OK);
	for (int i = 0; i < 3; i++) {
		can_message_t m = frame(0x10, 0, 0, 0, 0);
		mock_can_inject("vcan0", &m, 1);
	}
	/* the reader has read the port once (batching: the rest waits there until the period ends) */
	for (int tries = 0; tries < 5000 && mock_can_reads("vcan0") == 0; tries++)
		mock_zenoh_wait_puts(1, 1);
	CHECK(mock_can_reads("vcan0") >= 1 && mock_zenoh_put_count() == 0);
	zn_node_stop();
	CHECK(mock_zenoh_put_count() == 1 && mock_zenoh_put(0)->len == 48);
}

/* Immediate mode: a frame the reader reads while the node stops is published, even when the
 * publisher, watching the reader's direct puts, saw the stop first with nothing queued (it
 * used to leave then, and the reader's last frames stayed in the queue: read, never published
 * nor counted as dropped). */
static void *stop_node(void *arg)
{
	(void)arg;
	zn_node_stop();
	return NULL;
}

static void test_immediate_stop_publishes_frames_read_meanwhile(void)
{
	mock_reset();
	zn_node_config_t cfg = base_config(0);
	CHECK(zn_node_init(&cfg) == ESP_OK);
	can_message_t m = frame(0x10, 0, 0, 1, 1);
	mock_can_inject("vcan0", &m, 1);
	CHECK(mock_zenoh_wait_puts(1, WAIT_MS) == 1); /* put by the reader: the publisher now watches */
	CHECK(mock_can_wait_receiving("vcan0", WAIT_MS)); /* the reader back in its read */
	pthread_t t;
	CHECK(pthread_create(&t, NULL, stop_node, NULL) == 0);
	/* the publisher's watch (10 ms) sees the stop; the reader still waits in its read (200 ms) */
	nanosleep(&(struct timespec){ .tv_nsec = 50000000 }, NULL);
	m = frame(0x11, 0, 0, 1, 2);
	mock_can_inject("vcan0", &m, 2);
	pthread_join(t, NULL);
	CHECK(mock_zenoh_put_count() == 2);
}

static void inject_paced(size_t frames, size_t per_burst, long gap_ns, int64_t first_stamp)
{
	can_message_t m[64];
	for (size_t i = 0; i < frames; i += per_burst) {
		size_t n = frames - i < per_burst ? frames - i : per_burst;
		for (size_t k = 0; k < n; k++)
			m[k] = frame((uint32_t)((i + k) & 0x7FF), 0, 0, 1, (uint8_t)(i + k));
		mock_can_inject_burst("vcan0", m, n, first_stamp + (int64_t)i);
		nanosleep(&(struct timespec){ .tv_nsec = gap_ns }, NULL); /* the load's pace, not a wait */
	}
}

/* Immediate mode: frames queued together are read together, ZN_CAN_BURST_MAX per call,
 * and still published one sample per frame with their own stamps. */
static void test_burst_immediate(void)
{
	mock_reset();
	zn_node_config_t cfg = base_config(0);
	CHECK(zn_node_init(&cfg) == ESP_OK);
	size_t before = mock_can_reads("vcan0");
	inject_paced(200, 64, 0, 7000);
	check_published_frames(200, 7000, 0, WAIT_MS);
	size_t reads = mock_can_reads("vcan0") - before;
	CHECK(reads >= 1 && reads <= 4); /* 200 frames in ceil(200 / 64) reads; one each before */
	if (reads > 4)
		fprintf(stderr, "test_burst_immediate: %zu reads for 200 frames\n", reads);
	zn_node_stop();
}

/* Immediate mode: a burst's samples are put inside one zn_batch_start / stop (one write for the
 * burst, not one per frame), whether the reader puts them or the publisher takes them queued. */
static void test_burst_puts_held(void)
{
	mock_reset();
	zn_node_config_t cfg = base_config(0);
	CHECK(zn_node_init(&cfg) == ESP_OK);
	inject_paced(10, 10, 0, 5000); /* one burst the reader puts itself */
	CHECK(mock_zenoh_wait_puts(10, WAIT_MS) == 10);
	inject_paced(200, 64, 0, 6000); /* full bursts: queued, the publisher puts them */
	CHECK(mock_zenoh_wait_puts(210, WAIT_MS) == 210);
	CHECK(mock_zenoh_batch_misuse() == 0);
	/* a put the machine delayed past the stall bound sends the rest of its burst through the
	 * queue, where a frame left alone is put singly: the batches are judged without a stall */
	if (!stats_soon_has("\"direct_stalls\": 0")) {
		zn_node_stop();
		return;
	}
	unsigned first = mock_zenoh_put(0)->batch;
	CHECK(first != 0);
	for (size_t i = 1; i < 10; i++)
		CHECK(mock_zenoh_put(i)->batch == first);
	for (size_t i = 10; i < 210; i++)
		CHECK(mock_zenoh_put(i)->batch != 0 && mock_zenoh_put(i)->batch != first);
	zn_node_stop();
}

/* Batching mode: the reader wakes about once per period, not once per frame. */
static void test_burst_batching(void)
{
	mock_reset();
	zn_node_config_t cfg = base_config(20);
	CHECK(zn_node_init(&cfg) == ESP_OK);
	inject_paced(200, 1, 1000000, 9000); /* 200 frames, one a millisecond: 10 periods */
	check_published_frames(200, 9000, 0, WAIT_MS);
	size_t reads = mock_can_reads("vcan0");
	/* ~10 period ends, plus a stretch's first frame and its short first sleeps (1, 2, 4, 8 ms) */
	CHECK(reads >= 1 && reads <= 30);
	if (reads > 30)
		fprintf(stderr, "test_burst_batching: %zu reads for 200 frames\n", reads);
	zn_node_stop();
}

/* Batching mode with a port that holds little: the reader comes back before it fills
 * (the rate it measured, half the capacity), so a long period drops nothing (a reader
 * that slept its 1 s period dropped 120 of the 256 frames). */
static void test_burst_port_capacity(void)
{
	mock_reset();
	mock_can_set_capacity("vcan0", 128);
	zn_node_config_t cfg = base_config(1000);
	CHECK(zn_node_init(&cfg) == ESP_OK);
	/* 800 frames/s: the port is full in 160 ms, so the reader wakes about every 80 ms (half
	 * of it), with 80 ms to spare for a late wakeup on a busy machine */
	inject_paced(256, 8, 10000000, 3000);
	check_published_frames(256, 3000, 0, WAIT_MS);
	CHECK(mock_can_rx_drops("vcan0") == 0);
	if (mock_can_rx_drops("vcan0"))
		fprintf(stderr, "test_burst_port_capacity: the port dropped %zu frames\n", mock_can_rx_drops("vcan0"));
	zn_node_stop();
}

static void deliver(const uint8_t *payload, size_t len, const uint8_t *att, size_t att_len)
{
	CHECK(mock_zenoh_deliver("vehicle/can/tx", payload, len, att, att_len) == 0);
}

static void test_commands(void)
{
	mock_reset();
	zn_node_config_t cfg = base_config(0);
	CHECK(zn_node_init(&cfg) == ESP_OK);
	uint8_t wire[64];
	can_message_t a = frame(0x321, 0, 0, 3, 0x42), b = frame(0x1ABCDE, 1, 1, 2, 0);
	zn_wire_encode(&a, wire, 16);
	zn_wire_encode(&b, wire + 16, 16);
	deliver(wire, 16, NULL, 0);
	deliver(wire, 32, NULL, 0);
	CHECK(mock_can_wait_tx("vcan0", 3, WAIT_MS) == 3);
	can_message_t got = mock_can_tx("vcan0", 2);
	CHECK(got.identifier == 0x1ABCDE && got.extd && got.rtr && got.data_length_code == 2);

	uint8_t bad[16];
	memcpy(bad, wire, 16);
	bad[4] = 9;
	deliver(bad, 16, NULL, 0);	 /* dlc */
	deliver(wire, 17, NULL, 0);	 /* length */
	deliver(wire, 0, NULL, 0);	 /* length */
	memcpy(bad, wire, 16);
	bad[6] = 1;
	deliver(bad, 16, NULL, 0); /* reserved */
	memcpy(bad, wire + 16, 16);
	bad[8] = 1;
	deliver(bad, 16, NULL, 0); /* remote with data */
	uint8_t valid_then_bad[32];
	memcpy(valid_then_bad, wire, 16);
	memcpy(valid_then_bad + 16, wire, 16);
	valid_then_bad[16 + 5] = 0x80;
	deliver(valid_then_bad, 32, NULL, 0); /* flags: the valid first frame is not sent either */
	uint8_t garbage_att[5] = { 1, 2, 3, 4, 5 };
	deliver(wire, 16, garbage_att, sizeof(garbage_att)); /* attachment */
	uint8_t good_att[ZN_ATTACHMENT_HEADER + 8] = { ZN_ATTACHMENT_VERSION, 0, 1, 0 };
	deliver(wire, 16, good_att, sizeof(good_att)); /* a well-formed attachment is fine */
	CHECK(mock_can_wait_tx("vcan0", 4, WAIT_MS) == 4);
	CHECK(stats_has("\"dlc\": 1"));
	CHECK(stats_has("\"length\": 2"));
	CHECK(stats_has("\"reserved\": 1"));
	CHECK(stats_has("\"remote_data\": 1"));
	CHECK(stats_has("\"flags\": 1"));
	CHECK(stats_has("\"attachment\": 1"));
	CHECK(stats_soon_has("\"tx_frames\": 4"));
	CHECK(stats_has("\"tx_samples\": 10"));
	zn_node_stop();
}

/* A command that arrives while the node starts (its subscriber declared, the other buses, the
 * transmitters and the token not yet) is not taken: it was written before the bridge was ready,
 * and by a start that could still fail. Once init has returned, commands are. The one refused is
 * counted (tx_refused_closed), from each init on. */
static void test_command_during_start_is_not_taken(void)
{
	for (int init = 0; init < 2; init++) {
		mock_reset();
		uint8_t wire[16];
		can_message_t a = frame(0x321, 0, 0, 3, 0x42);
		zn_wire_encode(&a, wire, 16);
		mock_zenoh_deliver_on_declare("vehicle/can/tx", wire, 16);
		zn_node_config_t cfg = base_config(0);
		CHECK(zn_node_init(&cfg) == ESP_OK);
		CHECK(mock_can_tx_count("vcan0") == 0);
		CHECK(stats_has("\"tx_samples\": 0"));
		CHECK(stats_has("\"tx_refused_closed\": 1,")); /* the second init's own, not 2 */
		deliver(wire, 16, NULL, 0);
		CHECK(mock_can_wait_tx("vcan0", 1, WAIT_MS) == 1);
		CHECK(stats_soon_has("\"tx_samples\": 1"));
		CHECK(stats_has("\"tx_refused_closed\": 1,"));
		zn_node_stop();
	}
}

static void test_multi_bus_keys(void)
{
	mock_reset();
	zn_node_config_t cfg = base_config(0);
	strcpy(cfg.buses[0], "can0");
	strcpy(cfg.buses[1], "can1");
	cfg.bus_count = 2;
	CHECK(zn_node_init(&cfg) == ESP_OK);
	can_message_t m = frame(0x1, 0, 0, 0, 0);
	mock_can_inject("can1", &m, 1);
	CHECK(mock_zenoh_wait_puts(1, WAIT_MS) == 1);
	CHECK(strcmp(mock_zenoh_put(0)->key, "vehicle/can/can1/rx") == 0);
	uint8_t wire[16];
	zn_wire_encode(&m, wire, 16);
	CHECK(mock_zenoh_deliver("vehicle/can/can0/tx", wire, 16, NULL, 0) == 0);
	CHECK(mock_can_wait_tx("can0", 1, WAIT_MS) == 1 && mock_can_tx_count("can1") == 0);
	CHECK(mock_zenoh_has_token("vehicle/can/bridges/zenoh-node/can1/client"));
	zn_node_stop();
}

/* The bus lost under the running node (hub restarted): the reader reopens it and counts it,
 * frames and commands flow again, each once, sequence numbers go on. */
static void test_can_reopen(void)
{
	mock_reset();
	zn_node_config_t cfg = base_config(0);
	CHECK(zn_node_init(&cfg) == ESP_OK);
	can_message_t a = frame(0x101, 0, 0, 1, 1), c = frame(0x102, 0, 0, 1, 2), cmd = frame(0x201, 0, 0, 1, 3);
	mock_can_inject("vcan0", &a, 1);
	CHECK(mock_zenoh_wait_puts(1, WAIT_MS) == 1);
	mock_can_lose("vcan0");
	CHECK(stats_soon_has("\"can_reopens\": 1"));
	mock_can_inject("vcan0", &c, 2);
	CHECK(mock_zenoh_wait_puts(2, WAIT_MS) == 2);
	CHECK(mock_zenoh_put(1)->payload[0] == 0x02 && le64(mock_zenoh_put(1)->attachment + 4) == 1);
	uint8_t wire[16];
	zn_wire_encode(&cmd, wire, sizeof(wire));
	deliver(wire, 16, NULL, 0);
	CHECK(mock_can_wait_tx("vcan0", 1, WAIT_MS) == 1 && mock_can_tx("vcan0", 0).identifier == 0x201);
	CHECK(stats_soon_has("\"tx_frames\": 1"));
	CHECK(mock_zenoh_put_count() == 2 && mock_can_tx_count("vcan0") == 1); /* nothing twice */
	zn_node_stop();
}

static void test_config_checks(void)
{
	char err[256];
	zn_node_config_t cfg = base_config(0);
	CHECK(zn_node_check_config(&cfg, err, sizeof(err)) == ESP_OK);
	cfg.mode = (zn_mode_t)3;
	CHECK(zn_node_check_config(&cfg, err, sizeof(err)) != ESP_OK && strstr(err, "mode 3"));
	cfg = base_config(0);
	strcpy(cfg.key_prefix, "vehicle/*");
	CHECK(zn_node_check_config(&cfg, err, sizeof(err)) != ESP_OK && strstr(err, "key prefix"));
	cfg = base_config(0);
	cfg.allow[0] = (zn_id_range_t){ 0x100, 0x800, false };
	cfg.allow_count = 1;
	CHECK(zn_node_check_config(&cfg, err, sizeof(err)) != ESP_OK && strstr(err, "0x100-0x800"));
	cfg = base_config(0);
	strcpy(cfg.buses[1], "vcan0");
	cfg.bus_count = 2;
	CHECK(zn_node_check_config(&cfg, err, sizeof(err)) != ESP_OK && strstr(err, "twice"));
	cfg = base_config(0);
	cfg.router_address[0] = '\0';
	CHECK(zn_node_check_config(&cfg, err, sizeof(err)) != ESP_OK && strstr(err, "router"));
}

/* A session configuration that cannot work is a configuration error (exit code 2 on Linux);
 * and the port is told the largest message the node needs, so it reassembles nothing larger. */
static void test_open(void)
{
	mock_reset();
	zn_node_config_t cfg = base_config(0);
	mock_zenoh_open_result(ZN_PORT_ERR_CONFIG);
	CHECK(zn_node_init(&cfg) == ESP_ERR_INVALID_ARG);
	mock_reset();
	mock_zenoh_open_result(-1);
	CHECK(zn_node_init(&cfg) == ESP_FAIL);
	mock_reset();
	CHECK(zn_node_init(&cfg) == ESP_OK);
	size_t max = mock_zenoh_last_open().rx_message_max;
	CHECK(max >= ZN_BATCH_MAX_FRAMES * ZN_WIRE_FRAME_SIZE + ZN_ATTACHMENT_SIZE(ZN_BATCH_MAX_FRAMES));
	CHECK(max <= 64 * 1024); /* not Zenoh's 1 GiB */
	zn_node_stop();
}

/* Stats queries while the node stops, on another thread as Zenoh answers them: undeclaring the
 * queryable does not wait for a callback already running, so without the gate (zn_stats_on_query)
 * one could lock a bus lock stop has freed. A race: seen without the gate as a hang in that lock
 * once in about 250 rounds, so this mostly proves that stop neither hangs nor trips ASan with a
 * query inside the gate, not that the gate is there. */
static volatile int querying;

static void *query_loop(void *arg)
{
	(void)arg;
	char buf[8192];
	while (querying)
		mock_zenoh_query("vehicle/can/bridges/zenoh-node/stats", buf, sizeof(buf));
	return NULL;
}

static void test_stats_query_during_stop(void)
{
	for (int round = 0; round < 20; round++) {
		mock_reset();
		zn_node_config_t cfg = base_config(0);
		CHECK(zn_node_init(&cfg) == ESP_OK);
		pthread_t t;
		querying = 1;
		CHECK(pthread_create(&t, NULL, query_loop, NULL) == 0);
		CHECK(stats_soon_has("\"buses\""));
		zn_node_stop();
		querying = 0;
		pthread_join(t, NULL);
	}
}

/* A connection replaced between two polls of the routers (a TLS link's failed write: the router set is
 * the same at every poll) is counted in the stats all the same: samples put meanwhile were lost. */
static void test_connections_closed(void)
{
	mock_reset();
	zn_node_config_t cfg = base_config(0);
	CHECK(zn_node_init(&cfg) == ESP_OK);
	CHECK(stats_has("\"connections_closed\": 0,"));
	mock_zenoh_close_connection();
	mock_zenoh_close_connection();
	CHECK(stats_has("\"connections_closed\": 2,"));
	CHECK(stats_has("\"reconnects\": 0,"));
	zn_node_stop();
}

/* Frames put while the session has no connection went nowhere (Zenoh's put returns Ok): counted apart
 * from published and failed frames; once connected again they flow as before. */
static void test_unrouted_frames(void)
{
	mock_reset();
	zn_node_config_t cfg = base_config(0);
	CHECK(zn_node_init(&cfg) == ESP_OK);
	mock_zenoh_unrouted(1);
	for (int i = 0; i < 3; i++) {
		can_message_t m = frame(0x100 + (uint32_t)i, 0, 0, 1, (uint8_t)i);
		mock_can_inject("vcan0", &m, 1000 + i);
	}
	CHECK(stats_soon_has("\"unrouted_frames\": 3,"));
	CHECK(stats_has("\"published_frames\": 0,") && stats_has("\"publish_errors\": 0,"));
	mock_zenoh_unrouted(0);
	can_message_t m = frame(0x200, 0, 0, 1, 9);
	mock_can_inject("vcan0", &m, 2000);
	CHECK(mock_zenoh_wait_puts(4, WAIT_MS) == 4);
	CHECK(le64(mock_zenoh_put(3)->attachment + 4) == 3);
	CHECK(stats_soon_has("\"published_frames\": 1,"));
	zn_node_stop();
}

int main(void)
{
	test_open();
	test_immediate_mode();
	test_filters();
	test_batching();
	test_flush_on_stop();
	test_immediate_stop_publishes_frames_read_meanwhile();
	test_burst_immediate();
	test_burst_puts_held();
	test_burst_batching();
	test_burst_port_capacity();
	test_commands();
	test_command_during_start_is_not_taken();
	test_multi_bus_keys();
	test_can_reopen();
	test_config_checks();
	test_stats_query_during_stop();
	test_connections_closed();
	test_unrouted_frames();
	CHECK_DONE("test_node");
}
