/* test_faults.c - the seeded-fault port (ports/faulty) wrapped around the mock
 * ports, linked as zenoh-node-faulty is: each fault breaks exactly its path,
 * and without ZN_FAULT the wrapped bridge behaves as the plain one. */
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "check.h"
#include "zn_mock.h"
#include "zn_node.h"
#include "zn_wire.h"

#define WAIT_MS 5000

static zn_node_config_t immediate(void)
{
	zn_node_config_t cfg;
	zn_node_default_config(&cfg);
	cfg.publish_period_ms = 0;
	cfg.rx_queue_frames = 1024;
	return cfg;
}

static void inject(int n)
{
	for (int i = 0; i < n; i++) {
		can_message_t m = { .identifier = (uint32_t)i, .data_length_code = 1, .data = { (uint8_t)(0x10 + i) } };
		mock_can_inject("vcan0", &m, 1000 + i);
	}
}

/* Only the first fault spec of a process is read (as in the bridge): one per run. */
static void test_drop_every_second_sample(void)
{
	mock_reset();
	zn_node_config_t cfg = immediate();
	CHECK(zn_node_init(&cfg) == ESP_OK);
	inject(6);
	/* three of six arrive; the stats still claim six (what bridge_stats_agree catches) */
	CHECK(mock_zenoh_wait_puts(3, WAIT_MS) == 3);
	char buf[8192];
	for (int tries = 0; tries < WAIT_MS; tries++) {
		size_t n = mock_zenoh_query("vehicle/can/bridges/zenoh-node/stats", buf, sizeof(buf));
		if (n && strstr(buf, "\"published_samples\": 6"))
			break;
		mock_zenoh_wait_puts(4, 1);
	}
	CHECK(strstr(buf, "\"published_samples\": 6") != NULL);
	CHECK(mock_zenoh_put_count() == 3);
	for (size_t i = 0; i < 3; i++) /* samples 1, 3, 5 (ids 0, 2, 4) */
		CHECK(mock_zenoh_put(i)->payload[0] == 2 * i);
	/* commands are untouched by a CAN -> Zenoh fault */
	uint8_t wire[16];
	can_message_t c = { .identifier = 0x321, .data_length_code = 1, .data = { 0x42 } };
	zn_wire_encode(&c, wire, sizeof(wire));
	CHECK(mock_zenoh_deliver("vehicle/can/tx", wire, 16, NULL, 0) == 0);
	CHECK(mock_can_wait_tx("vcan0", 1, WAIT_MS) == 1 && mock_can_tx("vcan0", 0).data[0] == 0x42);
	zn_node_stop();
}

/* no-freshness: a command older than the deadline is written (the plain bridge refuses it). */
static void test_no_freshness(void)
{
	mock_reset();
	zn_node_config_t cfg = immediate();
	cfg.tx_max_age_ms = 100;
	CHECK(zn_node_init(&cfg) == ESP_OK);
	struct timespec ts;
	clock_gettime(CLOCK_REALTIME, &ts);
	int64_t old = ((int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec) - 2000000000LL;
	uint8_t wire[16], att[ZN_ATTACHMENT_SIZE(1)];
	can_message_t c = { .identifier = 0x321, .data_length_code = 1, .data = { 0x42 } };
	zn_wire_encode(&c, wire, sizeof(wire));
	zn_attachment_header(att, 1, 7);
	zn_attachment_set_time(att, 0, old);
	CHECK(mock_zenoh_deliver_at("vehicle/can/tx", wire, 16, att, sizeof(att), (uint64_t)old) == 0);
	CHECK(mock_can_wait_tx("vcan0", 1, WAIT_MS) == 1 && mock_can_tx("vcan0", 0).data[0] == 0x42);
	/* CAN -> Zenoh untouched */
	inject(2);
	CHECK(mock_zenoh_wait_puts(2, WAIT_MS) == 2);
	zn_node_stop();
}

/* txflip:2 on a 4-frame command: frames 2 and 4 flipped, counted per frame although the
 * transmitter writes the command as one burst. */
static void test_txflip_counts_frames_in_a_burst(void)
{
	mock_reset();
	zn_node_config_t cfg = immediate();
	CHECK(zn_node_init(&cfg) == ESP_OK);
	uint8_t wire[4 * 16];
	for (int i = 0; i < 4; i++) {
		can_message_t c = { .identifier = 0x321, .data_length_code = 1, .data = { (uint8_t)(0x40 + i) } };
		zn_wire_encode(&c, wire + 16 * i, 16);
	}
	CHECK(mock_zenoh_deliver("vehicle/can/tx", wire, sizeof(wire), NULL, 0) == 0);
	CHECK(mock_can_wait_tx("vcan0", 4, WAIT_MS) == 4);
	for (int i = 0; i < 4; i++)
		CHECK(mock_can_tx("vcan0", (size_t)i).data[0] == (uint8_t)((0x40 + i) ^ (i % 2)));
	zn_node_stop();
}

/* The frames of every put so far, in order (a sample holds one or a batch). */
static size_t published(can_message_t *out, size_t max)
{
	size_t n = 0;
	for (size_t i = 0; i < mock_zenoh_put_count(); i++) {
		size_t got = 0;
		const struct mock_put *put = mock_zenoh_put(i);
		CHECK(zn_wire_decode(put->payload, put->len, out + n, max - n, &got) == ZN_WIRE_OK);
		n += got;
	}
	return n;
}

/* flip:2@2.7 (bit 7 of data byte 2, every 2nd frame that has byte 2): 12 frames, of which the
 * dlc-2 and remote ones have no byte 2 and do not count; published one by one and then as one
 * batch, counted frame by frame either way. Spec: the flipped frames' expected data. */
static void test_flip_at_byte_bit(int period_ms)
{
	mock_reset();
	zn_node_config_t cfg = immediate();
	cfg.publish_period_ms = period_ms;
	CHECK(zn_node_init(&cfg) == ESP_OK);
	can_message_t sent[12];
	int has_byte2 = 0, expect_flipped[12];
	for (int i = 0; i < 12; i++) {
		sent[i] = (can_message_t){ .identifier = 0x0C0, .data_length_code = i % 4 == 1 ? 2 : 8,
					   .data = { (uint8_t)i, 0x11, 0x22, 0x33, 0x44, 0x55, 0x66, 0x77 } };
		if (i % 4 == 3) { /* a remote request: no data, never flipped */
			sent[i].rtr = 1;
			sent[i].data_length_code = 3;
			memset(sent[i].data, 0, sizeof(sent[i].data));
		}
		if (i % 4 == 1)
			memset(sent[i].data + 2, 0, 6); /* bytes beyond dlc are zero on the wire */
		int counted = sent[i].data_length_code > 2 && !sent[i].rtr;
		expect_flipped[i] = counted && ++has_byte2 % 2 == 0;
	}
	if (period_ms)
		mock_can_inject_burst("vcan0", sent, 12, 1000);
	else
		for (int i = 0; i < 12; i++)
			mock_can_inject("vcan0", &sent[i], 1000 + i);
	can_message_t got[12];
	for (int tries = 0; tries < 100 && published(got, 12) < 12; tries++)
		mock_zenoh_wait_puts(mock_zenoh_put_count() + 1, WAIT_MS / 100);
	CHECK(published(got, 12) == 12);
	if (period_ms)
		CHECK(mock_zenoh_put_count() < 12); /* batches, not one frame a sample */
	int flipped = 0;
	for (int i = 0; i < 12; i++) {
		can_message_t want = sent[i];
		if (expect_flipped[i])
			want.data[2] ^= 0x80;
		flipped += expect_flipped[i];
		CHECK(got[i].identifier == want.identifier && got[i].data_length_code == want.data_length_code);
		CHECK(memcmp(got[i].data, want.data, 8) == 0);
	}
	CHECK(flipped == 3); /* 6 frames have byte 2: the 2nd, 4th and 6th */
	zn_node_stop();
}

/* A malformed flip:N@BYTE.BIT seeds no fault at all (the bridge says so in its log). */
static void test_flip_at_refused(void)
{
	mock_reset();
	zn_node_config_t cfg = immediate();
	CHECK(zn_node_init(&cfg) == ESP_OK);
	for (int i = 0; i < 4; i++) {
		can_message_t m = { .identifier = 0x0C0, .data_length_code = 8, .data = { 1, 2, 3, 4, 5, 6, 7, 8 } };
		mock_can_inject("vcan0", &m, 1000 + i);
	}
	CHECK(mock_zenoh_wait_puts(4, WAIT_MS) == 4);
	can_message_t got[4];
	CHECK(published(got, 4) == 4);
	for (int i = 0; i < 4; i++)
		CHECK(got[i].data[0] == 1 && got[i].data[2] == 3 && got[i].data[7] == 8);
	zn_node_stop();
}

/* One fault per process (as in the bridge): argv[1] names it, none = drop:2. */
int main(int argc, char **argv)
{
	if (argc > 1 && strcmp(argv[1], "no-freshness") == 0) {
		setenv("ZN_FAULT", "no-freshness", 1);
		test_no_freshness();
	} else if (argc > 1 && strcmp(argv[1], "txflip") == 0) {
		setenv("ZN_FAULT", "txflip:2", 1);
		test_txflip_counts_frames_in_a_burst();
	} else if (argc > 1 && strcmp(argv[1], "flipat") == 0) {
		setenv("ZN_FAULT", "flip:2@2.7", 1);
		test_flip_at_byte_bit(0);
		test_flip_at_byte_bit(50);
	} else if (argc > 2 && strcmp(argv[1], "flipat-refused") == 0) {
		setenv("ZN_FAULT", argv[2], 1);
		test_flip_at_refused();
	} else {
		setenv("ZN_FAULT", "drop:2", 1);
		test_drop_every_second_sample();
	}
	CHECK_DONE("test_faults");
}
