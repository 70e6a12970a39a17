/* test_tx_queue.c - the command path under a stalled bus (mock ports): Zenoh's
 * callback never waits for CAN, a command that does not fit the bounded queue
 * is refused whole and counted, a failed frame abandons the rest of its
 * command (counted), stop during a stalled batch returns and frees nothing in
 * use (run under ASan), stop after a failed write writes what the bus takes at
 * once and abandons (counted) only what it does not; and a frame the wire
 * format cannot carry is skipped without costing the rest of its batch. Waiting commands leave in CAN
 * priority order (lowest arbitration id first, FIFO among equals); a command
 * older than tx_max_age_ms is refused on arrival or when the transmitter takes
 * it, never written (tx_rejected.stale), one stamped further ahead of the clock than
 * that refused on arrival (tx_rejected.future), one without a source time written
 * and counted (tx_unstamped). A command's frames are written in bursts; one
 * that finds the bus free is written by the callback itself, without waiting,
 * and what the bus did not take at once goes before anything queued. */
#include <pthread.h>
#include <string.h>
#include <time.h>

#include "check.h"
#include "zn_mock.h"
#include "zn_node.h"
#include "zn_port_os.h"
#include "zn_wire.h"

/* zn_internal.h (the component's, not its API): the order waiting commands leave in */
uint32_t zn_tx_arbitration_key(const can_message_t *msg);

#define WAIT_MS 5000
#define FAST_MS 50 /* a callback that queues takes microseconds; one CAN timeout is 100 ms */

static int64_t now_ms(void)
{
	struct timespec ts;
	clock_gettime(CLOCK_MONOTONIC, &ts);
	return ts.tv_sec * 1000 + ts.tv_nsec / 1000000;
}

static zn_node_config_t config(uint32_t period_ms)
{
	zn_node_config_t cfg;
	zn_node_default_config(&cfg);
	cfg.publish_period_ms = period_ms;
	cfg.rx_queue_frames = 1024;
	return cfg;
}

static int stats_soon_has(const char *needle)
{
	char buf[8192];
	size_t n = 0;
	for (int64_t end = now_ms() + WAIT_MS; now_ms() < end;) {
		n = mock_zenoh_query("vehicle/can/bridges/zenoh-node/stats", buf, sizeof(buf));
		if (n > 0 && strstr(buf, needle))
			return 1;
		nanosleep(&(struct timespec){ .tv_nsec = 1000000 }, NULL);
	}
	fprintf(stderr, "stats lack '%s': %.*s\n", needle, (int)n, buf);
	return 0;
}

/* A command of n frames, ids first..first+n-1 (11-bit, wrapping), data = frame number. */
static size_t command(uint8_t *wire, size_t n, uint32_t first)
{
	for (size_t i = 0; i < n; i++) {
		can_message_t m = { .identifier = (uint32_t)((first + i) & 0x7FF), .data_length_code = 2,
				    .data = { (uint8_t)i, (uint8_t)(i >> 8) } };
		zn_wire_encode(&m, wire + 16 * i, 16);
	}
	return 16 * n;
}

static int64_t deliver_ms(const uint8_t *wire, size_t len)
{
	int64_t t0 = now_ms();
	CHECK(mock_zenoh_deliver("vehicle/can/tx", wire, len, NULL, 0) == 0);
	return now_ms() - t0;
}

static uint8_t big[ZN_BATCH_MAX_FRAMES * 16];

/* zn_thread_start and zn_thread_join wrapped (CMakeLists.txt): stop tells the transmitter to stop,
 * then joins it, so a test can act at that moment (at_transmitter_join) and read the stats once the
 * transmitter has ended, before stop releases them (stats_at_stop). */
esp_err_t __real_zn_thread_start(zn_thread_t **out, const char *name, void (*fn)(void *), void *arg);
esp_err_t __wrap_zn_thread_start(zn_thread_t **out, const char *name, void (*fn)(void *), void *arg);
void __real_zn_thread_join(zn_thread_t *t);
void __wrap_zn_thread_join(zn_thread_t *t);

static zn_thread_t *transmitter;
static void (*at_transmitter_join)(void);
static char stats_at_stop[8192];

esp_err_t __wrap_zn_thread_start(zn_thread_t **out, const char *name, void (*fn)(void *), void *arg)
{
	esp_err_t rc = __real_zn_thread_start(out, name, fn, arg);
	if (rc == ESP_OK && strcmp(name, "zn-tx") == 0)
		transmitter = *out;
	return rc;
}

void __wrap_zn_thread_join(zn_thread_t *t)
{
	int tx = t && t == transmitter;
	if (tx && at_transmitter_join)
		at_transmitter_join();
	__real_zn_thread_join(t);
	if (tx)
		mock_zenoh_query("vehicle/can/bridges/zenoh-node/stats", stats_at_stop, sizeof(stats_at_stop));
}

static int stopped_with(const char *needle)
{
	if (strstr(stats_at_stop, needle))
		return 1;
	fprintf(stderr, "stats at stop lack '%s': %s\n", needle, stats_at_stop);
	return 0;
}

/* Two largest commands fill the 2048-frame queue; the third is refused whole. */
static void test_callback_never_waits_and_full_queue_refuses(void)
{
	mock_reset();
	zn_node_config_t cfg = config(0);
	CHECK(zn_node_init(&cfg) == ESP_OK);
	mock_can_stall("vcan0", 1);
	size_t len = command(big, 30, 0x100);
	int64_t took = deliver_ms(big, len); /* issue 19: this held the callback 3 s */
	if (took >= FAST_MS) {
		fprintf(stderr, "a 30-frame command on a stalled bus held the callback %lld ms\n", (long long)took);
		check_failures++;
		zn_node_stop();
		return; /* the rest needs a callback that does not wait */
	}
	mock_can_stall("vcan0", MOCK_HOLD); /* the first frame now waits until the stall is lifted */
	len = command(big, ZN_BATCH_MAX_FRAMES, 0x200);
	CHECK(deliver_ms(big, len) < FAST_MS);
	CHECK(deliver_ms(big, len) < FAST_MS); /* does not fit: refused at once */
	CHECK(stats_soon_has("\"tx_queue_full\": 1"));
	mock_can_stall("vcan0", 0);
	/* what was queued flows in order, each frame once; the refused command never */
	size_t sent = mock_can_wait_tx("vcan0", 30 + ZN_BATCH_MAX_FRAMES, WAIT_MS);
	CHECK(stats_soon_has("\"tx_frames\": 1054"));
	sent = mock_can_tx_count("vcan0");
	CHECK(sent == 30 + ZN_BATCH_MAX_FRAMES);
	for (size_t i = 0; i < sent && i < 30 + ZN_BATCH_MAX_FRAMES; i++) {
		can_message_t m = mock_can_tx("vcan0", i);
		size_t k = i < 30 ? i : i - 30;
		CHECK(m.identifier == ((i < 30 ? 0x100 : 0x200) + k) % 0x800 && m.data[0] == (uint8_t)k);
	}
	CHECK(stats_soon_has("\"tx_samples\": 3"));
	/* all three unstamped: the two written, not the one refused (it counted once, as tx_queue_full) */
	CHECK(stats_soon_has("\"tx_unstamped\": 2"));
	zn_node_stop();
}

/* A frame the bus does not take costs one timeout, and the rest of its command is abandoned. */
static void test_failed_frame_abandons_its_command(void)
{
	mock_reset();
	zn_node_config_t cfg = config(0);
	CHECK(zn_node_init(&cfg) == ESP_OK);
	mock_can_stall("vcan0", 1);
	size_t len = command(big, 30, 0x100);
	CHECK(deliver_ms(big, len) < FAST_MS);
	CHECK(stats_soon_has("\"can_tx_errors\": 1, \"tx_queue_full\": 0, \"tx_abandoned\": 29"));
	mock_can_stall("vcan0", 0);
	len = command(big, 2, 0x300);
	deliver_ms(big, len);
	CHECK(mock_can_wait_tx("vcan0", 2, WAIT_MS) == 2);
	CHECK(mock_can_tx("vcan0", 0).identifier == 0x300);
	zn_node_stop();
}

/* A command's frames go to the bus in bursts: 100 frames in two port calls (64 + 36),
 * in order (one call per frame before zn_can_send_burst). */
static void test_command_written_in_bursts(void)
{
	mock_reset();
	zn_node_config_t cfg = config(0);
	CHECK(zn_node_init(&cfg) == ESP_OK);
	size_t len = command(big, 100, 0x100);
	CHECK(deliver_ms(big, len) < FAST_MS);
	CHECK(mock_can_wait_tx("vcan0", 100, WAIT_MS) == 100);
	for (size_t k = 0; k < 100; k++)
		CHECK(mock_can_tx("vcan0", k).identifier == 0x100 + k && mock_can_tx("vcan0", k).data[0] == (uint8_t)k);
	CHECK(mock_can_tx_calls("vcan0") == 2);
	if (mock_can_tx_calls("vcan0") != 2)
		fprintf(stderr, "test_command_written_in_bursts: %zu transmit calls for 100 frames\n",
			mock_can_tx_calls("vcan0"));
	CHECK(stats_soon_has("\"tx_frames\": 100"));
	zn_node_stop();
}

static void *deliver_thread(void *arg)
{
	(void)arg;
	size_t len = command(big, ZN_BATCH_MAX_FRAMES, 0x400);
	mock_zenoh_deliver("vehicle/can/tx", big, len, NULL, 0);
	return NULL;
}

/* SIGTERM during a stalled batch: stop returns within a bound, ASan sees no use after free. */
static void test_stop_during_stalled_batch(void)
{
	mock_reset();
	zn_node_config_t cfg = config(0);
	CHECK(zn_node_init(&cfg) == ESP_OK);
	mock_can_stall("vcan0", 1);
	pthread_t t;
	pthread_create(&t, NULL, deliver_thread, NULL); /* Zenoh's callback thread */
	CHECK(stats_soon_has("\"tx_samples\": 1"));
	int64_t t0 = now_ms();
	zn_node_stop();
	int64_t took = now_ms() - t0;
	if (took >= 1000)
		fprintf(stderr, "stop during a stalled batch took %lld ms\n", (long long)took);
	CHECK(took < 1000);
	pthread_join(t, NULL);
	CHECK(mock_can_tx_count("vcan0") == 0);
	mock_can_stall("vcan0", 0);
}

/* Issue 19, defect 11: a frame the wire format refuses is counted and skipped, the rest published. */
static void test_bad_frame_does_not_cost_its_batch(void)
{
	mock_reset();
	zn_node_config_t cfg = config(20);
	cfg.batch_max_frames = 3;
	CHECK(zn_node_init(&cfg) == ESP_OK);
	can_message_t good = { .identifier = 0x10, .data_length_code = 1, .data = { 7 } };
	can_message_t bad = { .identifier = 0x11, .data_length_code = 9 };
	can_message_t good2 = { .identifier = 0x12, .data_length_code = 0 };
	mock_can_inject("vcan0", &good, 1);
	mock_can_inject("vcan0", &bad, 2);
	mock_can_inject("vcan0", &good2, 3);
	size_t frames = 0;
	for (size_t puts = 0; frames < 2 && mock_zenoh_wait_puts(puts + 1, WAIT_MS) > puts; puts++)
		frames += mock_zenoh_put(puts)->len / 16;
	CHECK(frames == 2);
	CHECK(mock_zenoh_put(0) && mock_zenoh_put(0)->payload[0] == 0x10);
	CHECK(stats_soon_has("\"invalid_frames\": 1"));
	CHECK(stats_soon_has("\"publish_errors\": 0"));
	zn_node_stop();
}

static int64_t realtime_ns(void)
{
	struct timespec ts;
	clock_gettime(CLOCK_REALTIME, &ts);
	return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

/* One frame, id (extended when ext), data byte 0 = tag. */
static size_t one_frame(uint8_t *wire, uint32_t id, int ext, uint8_t tag)
{
	can_message_t m = { .identifier = id, .extd = ext ? 1 : 0, .data_length_code = 1, .data = { tag } };
	zn_wire_encode(&m, wire, 16);
	return 16;
}

/* Several commands wait behind a stalled bus: they leave in arbitration order, FIFO among equals. */
static void test_priority_order(void)
{
	mock_reset();
	zn_node_config_t cfg = config(0);
	CHECK(zn_node_init(&cfg) == ESP_OK);
	mock_can_stall("vcan0", MOCK_HOLD);
	uint8_t w[16];
	/* the first is taken at once (or, if not yet, is first anyway) and holds the bus */
	static const struct {
		uint32_t id;
		int ext;
	} sent[] = { { 0x050, 0 }, { 0x500, 0 }, { 0x100 << 18, 1 }, { 0x100, 0 }, { 0x200, 0 },
		     { 0x100, 0 }, { 0x0FF, 0 }, { 0x100 << 18, 1 } };
	for (uint8_t i = 0; i < sizeof(sent) / sizeof(sent[0]); i++)
		CHECK(mock_zenoh_deliver("vehicle/can/tx", w, one_frame(w, sent[i].id, sent[i].ext, i), NULL, 0) == 0);
	CHECK(stats_soon_has("\"tx_samples\": 8"));
	mock_can_stall("vcan0", 0);
	/* 0x050; 0x0FF; std 0x100 twice in arrival order; ext 0x100<<18 (same base id, IDE recessive) twice; 0x200; 0x500 */
	static const uint8_t order[] = { 0, 6, 3, 5, 2, 7, 4, 1 };
	CHECK(mock_can_wait_tx("vcan0", 8, WAIT_MS) == 8);
	for (size_t i = 0; i < 8; i++) {
		can_message_t m = mock_can_tx("vcan0", i);
		if (m.data[0] != order[i])
			fprintf(stderr, "frame %zu on the bus: command %u (id 0x%X), expected command %u\n", i, m.data[0],
				(unsigned)m.identifier, order[i]);
		CHECK(m.data[0] == order[i]);
	}
	zn_node_stop();
}

/* Arbitration keys: the bus's order (11-bit base id, then standard before extended, data before remote). */
static void test_arbitration_key(void)
{
	can_message_t std_data = { .identifier = 0x100 }, std_rtr = { .identifier = 0x100, .rtr = 1 },
		      ext_data = { .identifier = 0x100 << 18, .extd = 1 },
		      ext_rtr = { .identifier = 0x100 << 18, .extd = 1, .rtr = 1 },
		      ext_low = { .identifier = 0x0FF << 18 | 0x3FFFF, .extd = 1 }, std_next = { .identifier = 0x101 };
	CHECK(zn_tx_arbitration_key(&ext_low) < zn_tx_arbitration_key(&std_data));
	CHECK(zn_tx_arbitration_key(&std_data) < zn_tx_arbitration_key(&std_rtr));
	CHECK(zn_tx_arbitration_key(&std_rtr) < zn_tx_arbitration_key(&ext_data));
	CHECK(zn_tx_arbitration_key(&ext_data) < zn_tx_arbitration_key(&ext_rtr));
	CHECK(zn_tx_arbitration_key(&ext_rtr) < zn_tx_arbitration_key(&std_next));
}

/* An attachment for one frame received at t_ns. */
static size_t attachment_at(uint8_t *att, int64_t t_ns)
{
	zn_attachment_header(att, 1, 0);
	zn_attachment_set_time(att, 0, t_ns);
	return ZN_ATTACHMENT_SIZE(1);
}

/* The source time: the attachment's when there is one, else the Zenoh timestamp, else none. */
static void test_stale_refused_on_arrival(void)
{
	mock_reset();
	zn_node_config_t cfg = config(0);
	cfg.tx_max_age_ms = 100;
	CHECK(zn_node_init(&cfg) == ESP_OK);
	uint8_t w[16], att[ZN_ATTACHMENT_SIZE(1)];
	int64_t now = realtime_ns(), old = now - 500 * 1000000LL;
	size_t n = one_frame(w, 0x10, 0, 1);
	CHECK(mock_zenoh_deliver_at("vehicle/can/tx", w, n, NULL, 0, (uint64_t)old) == 0); /* stale Zenoh time */
	n = one_frame(w, 0x10, 0, 2);
	CHECK(mock_zenoh_deliver_at("vehicle/can/tx", w, n, att, attachment_at(att, old), (uint64_t)now) == 0);
	n = one_frame(w, 0x10, 0, 3); /* the attachment's time wins over a stale Zenoh time */
	CHECK(mock_zenoh_deliver_at("vehicle/can/tx", w, n, att, attachment_at(att, realtime_ns()), (uint64_t)old) == 0);
	n = one_frame(w, 0x10, 0, 4); /* fresh Zenoh time, no attachment */
	CHECK(mock_zenoh_deliver_at("vehicle/can/tx", w, n, NULL, 0, (uint64_t)realtime_ns()) == 0);
	n = one_frame(w, 0x10, 0, 5); /* an attachment time of 0 is none: the Zenoh time decides */
	CHECK(mock_zenoh_deliver_at("vehicle/can/tx", w, n, att, attachment_at(att, 0), (uint64_t)old) == 0);
	n = one_frame(w, 0x10, 0, 6); /* no time at all: written, counted */
	CHECK(mock_zenoh_deliver_at("vehicle/can/tx", w, n, NULL, 0, 0) == 0);
	CHECK(mock_can_wait_tx("vcan0", 3, WAIT_MS) == 3);
	CHECK(stats_soon_has("\"tx_frames\": 3"));
	CHECK(stats_soon_has("\"tx_unstamped\": 1"));
	CHECK(stats_soon_has("\"stale\": 3}"));
	CHECK(mock_can_tx_count("vcan0") == 3);
	CHECK(mock_can_tx("vcan0", 0).data[0] == 3 && mock_can_tx("vcan0", 1).data[0] == 4 &&
	      mock_can_tx("vcan0", 2).data[0] == 6);
	zn_node_stop();

	mock_reset(); /* tx_max_age_ms 0: off, the stale one is written */
	cfg.tx_max_age_ms = 0;
	CHECK(zn_node_init(&cfg) == ESP_OK);
	n = one_frame(w, 0x10, 0, 7);
	CHECK(mock_zenoh_deliver_at("vehicle/can/tx", w, n, att, attachment_at(att, old), (uint64_t)old) == 0);
	CHECK(mock_can_wait_tx("vcan0", 1, WAIT_MS) == 1);
	CHECK(stats_soon_has("\"stale\": 0}"));
	zn_node_stop();
}

/* A source time further ahead of the clock than the deadline would never go stale, however late
 * the command arrives: refused on arrival (tx_rejected.future), whichever time it came from, and so
 * is an attachment time beyond int64; one ahead by less than the deadline is written. Off at 0. */
static void test_future_refused_on_arrival(void)
{
	mock_reset();
	zn_node_config_t cfg = config(0);
	cfg.tx_max_age_ms = 100;
	CHECK(zn_node_init(&cfg) == ESP_OK);
	uint8_t w[16], att[ZN_ATTACHMENT_SIZE(1)];
	int64_t hour = 3600 * 1000000000LL;
	size_t n = one_frame(w, 0x10, 0, 1); /* the attachment an hour ahead */
	CHECK(mock_zenoh_deliver_at("vehicle/can/tx", w, n, att, attachment_at(att, realtime_ns() + hour),
				    (uint64_t)realtime_ns()) == 0);
	n = one_frame(w, 0x10, 0, 2); /* the Zenoh time an hour ahead, no attachment */
	CHECK(mock_zenoh_deliver_at("vehicle/can/tx", w, n, NULL, 0, (uint64_t)(realtime_ns() + hour)) == 0);
	n = one_frame(w, 0x10, 0, 3); /* 2^63 as the attachment's u64: no fallback to a fresh Zenoh time */
	CHECK(mock_zenoh_deliver_at("vehicle/can/tx", w, n, att, attachment_at(att, INT64_MIN), (uint64_t)realtime_ns()) ==
	      0);
	n = one_frame(w, 0x10, 0, 4); /* all ones */
	CHECK(mock_zenoh_deliver_at("vehicle/can/tx", w, n, att, attachment_at(att, -1), (uint64_t)realtime_ns()) == 0);
	n = one_frame(w, 0x10, 0, 5); /* ahead by less than the deadline: a clock a little ahead, written */
	CHECK(mock_zenoh_deliver_at("vehicle/can/tx", w, n, att, attachment_at(att, realtime_ns() + 50 * 1000000LL), 0) ==
	      0);
	CHECK(mock_can_wait_tx("vcan0", 1, WAIT_MS) == 1);
	CHECK(stats_soon_has("\"tx_samples\": 5"));
	CHECK(stats_soon_has("\"future\": 4, \"stale\": 0}"));
	CHECK(stats_soon_has("\"tx_frames\": 1"));
	CHECK(mock_can_tx_count("vcan0") == 1 && mock_can_tx("vcan0", 0).data[0] == 5);
	zn_node_stop();

	mock_reset(); /* tx_max_age_ms 0: times are not judged, the one an hour ahead is written */
	cfg.tx_max_age_ms = 0;
	CHECK(zn_node_init(&cfg) == ESP_OK);
	n = one_frame(w, 0x10, 0, 6);
	CHECK(mock_zenoh_deliver_at("vehicle/can/tx", w, n, att, attachment_at(att, realtime_ns() + hour), 0) == 0);
	CHECK(mock_can_wait_tx("vcan0", 1, WAIT_MS) == 1);
	CHECK(stats_soon_has("\"future\": 0, \"stale\": 0}"));
	zn_node_stop();
}

/* A command fresh on arrival that waits behind a stalled bus past its deadline is never written. */
static void test_stale_in_queue(void)
{
	mock_reset();
	zn_node_config_t cfg = config(0);
	cfg.tx_max_age_ms = 100;
	CHECK(zn_node_init(&cfg) == ESP_OK);
	mock_can_stall("vcan0", MOCK_HOLD);
	uint8_t w[16];
	int64_t t0 = realtime_ns();
	CHECK(mock_zenoh_deliver_at("vehicle/can/tx", w, one_frame(w, 0x10, 0, 1), NULL, 0, (uint64_t)t0) == 0);
	CHECK(mock_zenoh_deliver_at("vehicle/can/tx", w, one_frame(w, 0x20, 0, 2), NULL, 0, (uint64_t)t0) == 0);
	CHECK(mock_zenoh_deliver_at("vehicle/can/tx", w, one_frame(w, 0x30, 0, 3), NULL, 0, 0) == 0); /* unstamped */
	CHECK(stats_soon_has("\"tx_samples\": 3"));
	CHECK(stats_soon_has("\"stale\": 0}")); /* all three fresh on arrival */
	/* the bus stays stalled until the queued commands are past their deadline (the aging under test) */
	while (realtime_ns() < t0 + 150 * 1000000LL)
		nanosleep(&(struct timespec){ .tv_nsec = 5000000 }, NULL);
	mock_can_stall("vcan0", 0);
	CHECK(stats_soon_has("\"stale\": 1}"));
	CHECK(stats_soon_has("\"tx_frames\": 2"));
	CHECK(mock_can_tx_count("vcan0") == 2); /* the one held on the bus, and the unstamped one */
	CHECK(mock_can_tx("vcan0", 0).data[0] == 1 && mock_can_tx("vcan0", 1).data[0] == 3);
	zn_node_stop();
}

/* A command taken fresh from the queue waits for a busy bus at most what is left of its
 * deadline: refused as stale when it runs out (not written late), the bus not counted as failed. */
static void test_stale_waiting_for_the_bus(void)
{
	mock_reset();
	zn_node_config_t cfg = config(0);
	cfg.tx_max_age_ms = 60;
	CHECK(zn_node_init(&cfg) == ESP_OK);
	mock_can_stall("vcan0", 1); /* busy: each transmit waits its timeout, then fails */
	uint8_t w[16];
	CHECK(mock_zenoh_deliver_at("vehicle/can/tx", w, one_frame(w, 0x10, 0, 1), NULL, 0, (uint64_t)realtime_ns()) == 0);
	CHECK(stats_soon_has("\"stale\": 1}"));
	CHECK(stats_soon_has("\"can_tx_errors\": 0"));
	mock_can_stall("vcan0", 0);
	CHECK(mock_zenoh_deliver_at("vehicle/can/tx", w, one_frame(w, 0x20, 0, 2), NULL, 0, (uint64_t)realtime_ns()) == 0);
	CHECK(stats_soon_has("\"tx_frames\": 1"));
	CHECK(mock_can_tx_count("vcan0") == 1 && mock_can_tx("vcan0", 0).data[0] == 2); /* the stale one never */
	zn_node_stop();
}

/* A bus that takes one frame every 10 ms (a device queue draining onto a busy bus): a 64-frame
 * command with a 100 ms deadline has about 10 of its frames written, the rest refused as stale
 * once the deadline runs out, not written late. The port's timeout holds per frame, so a burst
 * written with the deadline as its timeout went on for as long as the bus kept taking frames. */
static void test_stale_on_a_slow_bus(void)
{
	mock_reset();
	zn_node_config_t cfg = config(0);
	cfg.tx_max_age_ms = 100;
	CHECK(zn_node_init(&cfg) == ESP_OK);
	mock_can_tx_room("vcan0", 0);
	int64_t t0 = realtime_ns();
	size_t len = command(big, 64, 0x100);
	CHECK(mock_zenoh_deliver_at("vehicle/can/tx", big, len, NULL, 0, (uint64_t)t0) == 0);
	while (realtime_ns() < t0 + 800 * 1000000LL) { /* bounded: 8 deadlines of one frame each 10 ms */
		mock_can_tx_room("vcan0", 1);
		nanosleep(&(struct timespec){ .tv_nsec = 10000000 }, NULL);
	}
	size_t sent = mock_can_tx_count("vcan0");
	if (sent > 12)
		fprintf(stderr, "test_stale_on_a_slow_bus: %zu of 64 frames written, within %lld ms\n", sent,
			(long long)((realtime_ns() - t0) / 1000000));
	CHECK(sent <= 12); /* 100 ms at one frame each 10 ms, and the one waiting when it ran out */
	CHECK(stats_soon_has("\"stale\": 1}"));
	CHECK(stats_soon_has("\"can_tx_errors\": 0"));
	mock_can_tx_room("vcan0", -1);
	zn_node_stop();
}

/* A command that finds the bus free is written by Zenoh's callback itself before it returns
 * (no transmitter wakeup): every frame from the delivering thread, in bursts, counted in
 * tx_direct_frames as well as tx_frames. */
static void test_free_bus_written_by_the_callback(void)
{
	mock_reset();
	zn_node_config_t cfg = config(0);
	CHECK(zn_node_init(&cfg) == ESP_OK);
	size_t len = command(big, 1, 0x100);
	CHECK(mock_zenoh_deliver("vehicle/can/tx", big, len, NULL, 0) == 0);
	len = command(big, 100, 0x200);
	CHECK(mock_zenoh_deliver("vehicle/can/tx", big, len, NULL, 0) == 0);
	size_t sent = mock_can_tx_count("vcan0"), mine = 0;
	for (size_t i = 0; i < sent; i++)
		mine += (size_t)mock_can_tx_by("vcan0", i, pthread_self());
	if (sent != 101 || mine != 101)
		fprintf(stderr, "test_free_bus_written_by_the_callback: %zu of 101 frames written when the callbacks "
				"returned, %zu by the callback\n",
			sent, mine);
	CHECK(sent == 101 && mine == 101);
	CHECK(mock_can_tx_calls("vcan0") == 3); /* 1, then 64 + 36 */
	CHECK(stats_soon_has("\"tx_frames\": 101"));
	CHECK(stats_soon_has("\"tx_direct_frames\": 101"));
	zn_node_stop();
}

/* The bus takes 10 frames of a 30-frame command at once: the callback writes those and returns;
 * the transmitter writes the other 20 once the bus has room, before the commands that came
 * meanwhile, even one of higher priority (a command is never interleaved with another). */
static void test_rest_of_a_direct_write_goes_first(void)
{
	mock_reset();
	zn_node_config_t cfg = config(0);
	CHECK(zn_node_init(&cfg) == ESP_OK);
	mock_can_tx_room("vcan0", 10);
	size_t len = command(big, 30, 0x300);
	CHECK(deliver_ms(big, len) < FAST_MS);
	CHECK(mock_can_tx_count("vcan0") == 10);
	uint8_t w[16];
	CHECK(mock_zenoh_deliver("vehicle/can/tx", w, one_frame(w, 0x001, 0, 0xA1), NULL, 0) == 0);
	CHECK(mock_zenoh_deliver("vehicle/can/tx", w, one_frame(w, 0x7FF, 0, 0xA2), NULL, 0) == 0);
	CHECK(stats_soon_has("\"tx_samples\": 3"));
	mock_can_tx_room("vcan0", -1);
	CHECK(mock_can_wait_tx("vcan0", 32, WAIT_MS) == 32);
	for (size_t i = 0; i < 30; i++) {
		can_message_t m = mock_can_tx("vcan0", i);
		CHECK(m.identifier == 0x300 + i && m.data[0] == (uint8_t)i);
		CHECK(mock_can_tx_by("vcan0", i, pthread_self()) == (i < 10));
	}
	CHECK(mock_can_tx("vcan0", 30).data[0] == 0xA1 && mock_can_tx("vcan0", 31).data[0] == 0xA2);
	CHECK(stats_soon_has("\"tx_frames\": 32"));
	CHECK(stats_soon_has("\"tx_direct_frames\": 10"));
	CHECK(stats_soon_has("\"can_tx_errors\": 0, \"tx_queue_full\": 0, \"tx_abandoned\": 0"));
	zn_node_stop();
}

/* Commands queued behind a busy bus leave together: after the one the bus held, the 20 single-frame
 * commands that waited go in one port call (Linux: one sendmmsg), in arbitration order. */
static void test_queued_commands_written_together(void)
{
	mock_reset();
	zn_node_config_t cfg = config(0);
	CHECK(zn_node_init(&cfg) == ESP_OK);
	mock_can_tx_room("vcan0", 0); /* the first command waits in the transmitter for room */
	size_t len = command(big, 1, 0x700);
	CHECK(deliver_ms(big, len) < FAST_MS);
	uint8_t w[16];
	for (uint8_t i = 0; i < 20; i++) /* ids falling: the heap, not arrival, decides the order */
		CHECK(mock_zenoh_deliver("vehicle/can/tx", w, one_frame(w, 0x300 - i, 0, i), NULL, 0) == 0);
	CHECK(stats_soon_has("\"tx_samples\": 21"));
	mock_can_tx_room("vcan0", -1);
	CHECK(mock_can_wait_tx("vcan0", 21, WAIT_MS) == 21);
	CHECK(mock_can_tx("vcan0", 0).identifier == 0x700);
	for (size_t i = 1; i < 21; i++)
		CHECK(mock_can_tx("vcan0", i).data[0] == 20 - i);
	if (mock_can_tx_calls("vcan0") != 2)
		fprintf(stderr, "test_queued_commands_written_together: %zu transmit calls for 1 + 20 commands\n",
			mock_can_tx_calls("vcan0"));
	CHECK(mock_can_tx_calls("vcan0") == 2);
	CHECK(stats_soon_has("\"tx_frames\": 21"));
	zn_node_stop();
}

/* A group the bus takes in part: the command cut in its frames finishes next, whole and alone,
 * before a command of higher priority that came meanwhile, and before the command behind it that
 * had not begun (back in the heap, then grouped with the newcomer); nothing is lost. */
static void test_group_taken_in_part(void)
{
	mock_reset();
	zn_node_config_t cfg = config(0);
	CHECK(zn_node_init(&cfg) == ESP_OK);
	mock_can_tx_room("vcan0", 0);
	static uint8_t wire[4][16 * 5];
	static const struct {
		uint32_t id;
		size_t frames;
	} cmd[] = { { 0x100, 3 }, { 0x200, 1 }, { 0x300, 5 }, { 0x400, 2 } };
	for (size_t i = 0; i < 4; i++)
		CHECK(mock_zenoh_deliver("vehicle/can/tx", wire[i], command(wire[i], cmd[i].frames, cmd[i].id), NULL, 0) ==
		      0);
	CHECK(stats_soon_has("\"tx_samples\": 4"));
	mock_can_tx_room("vcan0", 6); /* 0x100's 3 frames, then of the group 0x200 and two of 0x300 */
	CHECK(mock_can_wait_tx("vcan0", 6, WAIT_MS) == 6);
	uint8_t w[16];
	CHECK(mock_zenoh_deliver("vehicle/can/tx", w, one_frame(w, 0x050, 0, 0xA1), NULL, 0) == 0);
	CHECK(stats_soon_has("\"tx_samples\": 5"));
	mock_can_tx_room("vcan0", -1);
	CHECK(mock_can_wait_tx("vcan0", 12, WAIT_MS) == 12);
	static const uint32_t order[] = { 0x100, 0x101, 0x102, 0x200, 0x300, 0x301,
					  0x302, 0x303, 0x304, 0x050, 0x400, 0x401 };
	for (size_t i = 0; i < 12; i++) {
		if (mock_can_tx("vcan0", i).identifier != order[i])
			fprintf(stderr, "test_group_taken_in_part: frame %zu is 0x%X, expected 0x%X\n", i,
				(unsigned)mock_can_tx("vcan0", i).identifier, (unsigned)order[i]);
		CHECK(mock_can_tx("vcan0", i).identifier == order[i]);
	}
	/* 0x100; the group; the rest of 0x300; 0x050 and 0x400 together */
	CHECK(mock_can_tx_calls("vcan0") == 4);
	/* one write took nothing (the callback's, at first): the rest of 0x300 waited for room as the
	 * transmitter's next, never tried again in a group */
	CHECK(mock_can_wait_tx_empty("vcan0", 0, 0) == 1);
	CHECK(stats_soon_has("\"tx_frames\": 12"));
	CHECK(stats_soon_has("\"can_tx_errors\": 0, \"tx_queue_full\": 0, \"tx_abandoned\": 0"));
	zn_node_stop();
}

/* A group the bus takes none of at once: its first command is written alone, with the bus's
 * timeouts, the others wait in their places and then go alone too (a full bus is not asked
 * again per command); nothing is lost or abandoned. */
static void test_group_taken_in_none(void)
{
	mock_reset();
	zn_node_config_t cfg = config(0);
	CHECK(zn_node_init(&cfg) == ESP_OK);
	mock_can_tx_room("vcan0", 0); /* the first command: the callback's write takes none, the transmitter waits */
	uint8_t w[16];
	for (uint8_t i = 0; i < 4; i++)
		CHECK(mock_zenoh_deliver("vehicle/can/tx", w, one_frame(w, 0x100u * (i + 1u), 0, i), NULL, 0) == 0);
	CHECK(stats_soon_has("\"tx_samples\": 4"));
	mock_can_tx_room("vcan0", 1); /* the first goes; the group of the other three finds no room */
	CHECK(mock_can_wait_tx_empty("vcan0", 2, WAIT_MS) == 2);
	mock_can_tx_room("vcan0", -1);
	CHECK(mock_can_wait_tx("vcan0", 4, WAIT_MS) == 4);
	for (size_t i = 0; i < 4; i++)
		CHECK(mock_can_tx("vcan0", i).identifier == 0x100u * (i + 1) && mock_can_tx("vcan0", i).data[0] == i);
	CHECK(mock_can_tx_calls("vcan0") == 4); /* after a group the bus took none of, each alone (tx_solo) */
	CHECK(stats_soon_has("\"tx_frames\": 4"));
	CHECK(stats_soon_has("\"can_tx_errors\": 0, \"tx_queue_full\": 0, \"tx_abandoned\": 0"));
	zn_node_stop();
}

/* A write failed (the bus stalled past its timeout) as stop began, and the bus took frames again
 * right after: the commands queued meanwhile are still written at stop (with a timeout of 0), not
 * abandoned for a failure the bus has recovered from. */
static void stall_ends(void)
{
	CHECK(mock_can_stall_ends("vcan0") == 1); /* the transmitter's write of the first command */
}

/* Starts the node with its first command (0x100) in the transmitter's write, held by the bus:
 * what is delivered next queues behind it. */
static void start_with_a_held_write(void)
{
	mock_reset();
	zn_node_config_t cfg = config(0);
	CHECK(zn_node_init(&cfg) == ESP_OK);
	mock_can_stall("vcan0", MOCK_HOLD);
	uint8_t w[16];
	CHECK(mock_zenoh_deliver("vehicle/can/tx", w, one_frame(w, 0x100, 0, 0), NULL, 0) == 0);
	CHECK(mock_can_wait_tx_held("vcan0", 1, WAIT_MS) == 1);
}

static void test_stop_writes_what_a_recovered_bus_takes(void)
{
	start_with_a_held_write();
	uint8_t w[16];
	size_t len = command(big, 3, 0x200);
	CHECK(mock_zenoh_deliver("vehicle/can/tx", big, len, NULL, 0) == 0);
	CHECK(mock_zenoh_deliver("vehicle/can/tx", w, one_frame(w, 0x300, 0, 2), NULL, 0) == 0);
	CHECK(stats_soon_has("\"tx_samples\": 3"));
	at_transmitter_join = stall_ends;
	zn_node_stop();
	at_transmitter_join = NULL;
	CHECK(mock_can_tx_count("vcan0") == 4);
	CHECK(mock_can_tx("vcan0", 0).identifier == 0x200 && mock_can_tx("vcan0", 3).identifier == 0x300);
	CHECK(stopped_with("\"tx_frames\": 4, \"can_tx_errors\": 1, \"tx_queue_full\": 0, \"tx_abandoned\": 0,"));
}

/* The same with a bus that stays stalled: stop ends after the one failed write, not a timeout per
 * command queued, and abandons them, counted. */
static void stall_stays(void)
{
	mock_can_stall("vcan0", 1); /* the held write fails at its timeout, and every write after it */
}

static void test_stop_on_a_stalled_bus_abandons(void)
{
	start_with_a_held_write();
	uint8_t w[16];
	for (uint8_t i = 1; i <= 20; i++) /* one 100 ms timeout each, were they tried */
		CHECK(mock_zenoh_deliver("vehicle/can/tx", w, one_frame(w, 0x200u + i, 0, i), NULL, 0) == 0);
	CHECK(stats_soon_has("\"tx_samples\": 21"));
	at_transmitter_join = stall_stays;
	int64_t t0 = now_ms();
	zn_node_stop();
	int64_t took = now_ms() - t0;
	at_transmitter_join = NULL;
	if (took >= 1000)
		fprintf(stderr, "stop with 20 commands queued on a stalled bus took %lld ms\n", (long long)took);
	CHECK(took < 1000);
	CHECK(mock_can_tx_count("vcan0") == 0);
	CHECK(stopped_with("\"tx_frames\": 0, \"can_tx_errors\": 1, \"tx_queue_full\": 0, \"tx_abandoned\": 20,"));
	mock_can_stall("vcan0", 0);
}

/* Runs every test, or the one named by argv[1] (to run one against other code). */
int main(int argc, char **argv)
{
	static const struct {
		const char *name;
		void (*fn)(void);
	} tests[] = {
		{ "full_queue", test_callback_never_waits_and_full_queue_refuses },
		{ "abandon", test_failed_frame_abandons_its_command },
		{ "bursts", test_command_written_in_bursts },
		{ "stop", test_stop_during_stalled_batch },
		{ "stop_recovered", test_stop_writes_what_a_recovered_bus_takes },
		{ "stop_stalled", test_stop_on_a_stalled_bus_abandons },
		{ "bad_frame", test_bad_frame_does_not_cost_its_batch },
		{ "priority", test_priority_order },
		{ "arbitration_key", test_arbitration_key },
		{ "stale_arrival", test_stale_refused_on_arrival },
		{ "future_arrival", test_future_refused_on_arrival },
		{ "stale_queue", test_stale_in_queue },
		{ "stale_waiting", test_stale_waiting_for_the_bus },
		{ "stale_slow_bus", test_stale_on_a_slow_bus },
		{ "direct", test_free_bus_written_by_the_callback },
		{ "direct_rest", test_rest_of_a_direct_write_goes_first },
		{ "together", test_queued_commands_written_together },
		{ "group_part", test_group_taken_in_part },
		{ "group_none", test_group_taken_in_none },
	};
	for (size_t i = 0; i < sizeof(tests) / sizeof(tests[0]); i++)
		if (argc < 2 || strcmp(argv[1], tests[i].name) == 0)
			tests[i].fn();
	CHECK_DONE("test_tx_queue");
}
