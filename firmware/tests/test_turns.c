/* test_turns.c - batching mode's turns (zn_rx.c) on mock ports, with zn_put
 * wrapped (-Wl,--wrap=zn_put) so a put can be held as a frozen router holds it:
 * a period wakes one of the bridge's threads, which reads the port and puts
 * the batch itself; a stalled put never leaves the port unread (counted in
 * direct_stalls); stop during a stalled put waits for it and loses nothing. */
#include <dirent.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "check.h"
#include "le64.h"
#include "zn_mock.h"
#include "published.h"
#include "zn_node.h"

#define WAIT_MS 5000
#define PERIOD_MS 10
#define TOKEN "vehicle/can/bridges/zenoh-node/vcan0/client"

/* ---- the put gate: closed, every put waits until it opens ---- */
static pthread_mutex_t gate_lock = PTHREAD_MUTEX_INITIALIZER;
static pthread_cond_t gate_cond = PTHREAD_COND_INITIALIZER;
static int gate_closed, held; /* puts waiting at the gate now */
static int failing;	       /* every put fails (as a closed session's) */

int __real_zn_put(zn_publisher_t *pub, const uint8_t *payload, size_t len, const uint8_t *attachment,
		  size_t attachment_len);
int __wrap_zn_put(zn_publisher_t *pub, const uint8_t *payload, size_t len, const uint8_t *attachment,
		  size_t attachment_len);
int __wrap_zn_put(zn_publisher_t *pub, const uint8_t *payload, size_t len, const uint8_t *attachment,
		  size_t attachment_len)
{
	pthread_mutex_lock(&gate_lock);
	if (gate_closed) {
		held++;
		pthread_cond_broadcast(&gate_cond);
		while (gate_closed)
			pthread_cond_wait(&gate_cond, &gate_lock);
		held--;
	}
	int fail = failing;
	pthread_mutex_unlock(&gate_lock);
	return fail ? -1 : __real_zn_put(pub, payload, len, attachment, attachment_len);
}

static void gate(int closed)
{
	pthread_mutex_lock(&gate_lock);
	gate_closed = closed;
	pthread_cond_broadcast(&gate_cond);
	pthread_mutex_unlock(&gate_lock);
}

/* Waits up to ms until a put is held at the closed gate (the bridge is inside a stalled put). */
static int wait_held_ms(int ms)
{
	struct timespec deadline = mock_deadline(ms);
	pthread_mutex_lock(&gate_lock);
	while (!held && pthread_cond_timedwait(&gate_cond, &gate_lock, &deadline) == 0)
		;
	int got = held;
	pthread_mutex_unlock(&gate_lock);
	return got;
}

static int wait_held(void)
{
	return wait_held_ms(WAIT_MS);
}

/* ---- helpers ---- */
static int64_t now_ns(void)
{
	struct timespec ts;
	clock_gettime(CLOCK_MONOTONIC, &ts);
	return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

static zn_node_config_t batching(void)
{
	zn_node_config_t cfg;
	zn_node_default_config(&cfg);
	cfg.publish_period_ms = PERIOD_MS;
	cfg.rx_queue_frames = 4096;
	return cfg;
}

/* Voluntary context switches so far of the bridge's CAN reader and publisher threads. */
static long bridge_switches(void)
{
	long total = 0;
	DIR *d = opendir("/proc/self/task");
	struct dirent *e;
	while (d && (e = readdir(d))) {
		char path[300], comm[32] = "", line[128];
		snprintf(path, sizeof(path), "/proc/self/task/%s/comm", e->d_name);
		FILE *f = fopen(path, "r");
		if (!f)
			continue;
		int got = fgets(comm, sizeof(comm), f) != NULL;
		fclose(f);
		if (!got || (strncmp(comm, "zn-can", 6) != 0 && strncmp(comm, "zn-pub", 6) != 0))
			continue;
		snprintf(path, sizeof(path), "/proc/self/task/%s/status", e->d_name);
		if (!(f = fopen(path, "r")))
			continue;
		while (fgets(line, sizeof(line), f))
			if (strncmp(line, "voluntary_ctxt_switches:", 24) == 0)
				total += atol(line + 24);
		fclose(f);
	}
	if (d)
		closedir(d);
	return total;
}

/* Frame i of a run: its id and data say i, its stamp is first_stamp + i. */
static void inject(size_t i, int64_t first_stamp)
{
	can_message_t m;
	memset(&m, 0, sizeof(m));
	m.identifier = (uint32_t)(i & 0x7FF);
	m.data_length_code = 2;
	m.data[0] = (uint8_t)i;
	m.data[1] = (uint8_t)(i >> 8);
	mock_can_inject("vcan0", &m, first_stamp + (int64_t)i);
}

static void pace_ms(long ms)
{
	nanosleep(&(struct timespec){ .tv_nsec = ms * 1000000 }, NULL); /* the load's pace, not a wait */
}

/* A counter of the bus's stats (the first of that name), or -1 when absent. */
static long long counter(const char *name)
{
	char buf[8192], key[64];
	mock_zenoh_query("vehicle/can/bridges/zenoh-node/stats", buf, sizeof(buf)); /* NUL-terminated */
	snprintf(key, sizeof(key), "\"%s\": ", name);
	const char *at = strstr(buf, key);
	return at ? atoll(at + strlen(key)) : -1;
}

/* Whether a counter of the stats reaches value within WAIT_MS (the puts seen by the mock have
 * not necessarily returned to the bridge yet). */
static int counter_reaches(const char *name, long long value)
{
	for (int waited_ms = 0; waited_ms < WAIT_MS; waited_ms++) {
		if (counter(name) == value)
			return 1;
		mock_zenoh_wait_puts(MOCK_MAX_PUTS, 1); /* a bounded 1 ms poll */
	}
	return 0;
}

/* ---- tests ---- */

/* A frame a millisecond, 10 a period: once the stretch's first short sleeps are over, a
 * period wakes one thread once (it drains and puts), not the reader and the publisher each
 * (2 a period before: the reader drained, the publisher was woken to put). */
static void test_one_wakeup_per_period(void)
{
	mock_reset();
	zn_node_config_t cfg = batching();
	CHECK(zn_node_init(&cfg) == ESP_OK);
	size_t frames = 0;
	for (; frames < 100; frames++) { /* the stretch starts, its sleeps grow to the period */
		inject(frames, 1000);
		pace_ms(1);
	}
	long switches = bridge_switches();
	int64_t start = now_ns();
	for (; frames < 500; frames++) {
		inject(frames, 1000);
		pace_ms(1);
	}
	double periods = (double)(now_ns() - start) / (PERIOD_MS * 1e6);
	double per_period = (double)(bridge_switches() - switches) / periods;
	check_published_frames(frames, 1000, 1, WAIT_MS);
	printf("test_one_wakeup_per_period: %.2f voluntary switches of zn-can and zn-pub per period (%.0f periods)\n",
	       per_period, periods);
	CHECK(per_period <= 1.5);
	zn_node_stop();
}

/* Frames at 1 per ms: `before` of them, then one whose batch's put is held (returns once a
 * put is held), then `during` more while it is; returns how many were injected. */
static size_t load_around_a_held_put(size_t before, size_t during, int64_t first_stamp)
{
	size_t frames = 0;
	for (; frames < before; frames++) {
		inject(frames, first_stamp);
		pace_ms(1);
	}
	gate(1);
	inject(frames++, first_stamp);
	CHECK(wait_held() == 1);
	for (size_t i = 0; i < during; i++, frames++) {
		inject(frames, first_stamp);
		pace_ms(1);
	}
	return frames;
}

/* A put held for 300 ms (a frozen router): the port, which holds 64 frames (64 ms of this
 * load), is read meanwhile, nothing is lost, the stall is counted, and once the put returns
 * everything goes out in order. */
static void test_stalled_put_keeps_reading(void)
{
	mock_reset();
	mock_can_set_capacity("vcan0", 64);
	zn_node_config_t cfg = batching();
	CHECK(zn_node_init(&cfg) == ESP_OK);
	size_t frames = load_around_a_held_put(50, 300, 5000);
	/* the stats say a put is stuck and what waits behind it (300 ms of load since it was held) */
	CHECK(counter("put_running_ms") >= 250);
	CHECK(counter("rx_queued") >= 250);
	gate(0);
	check_published_frames(frames, 5000, 1, WAIT_MS);
	CHECK(counter_reaches("put_running_ms", 0));
	CHECK(counter_reaches("rx_queued", 0));
	CHECK(mock_can_rx_drops("vcan0") == 0);
	if (mock_can_rx_drops("vcan0"))
		fprintf(stderr, "the port dropped %zu frames while a put stalled\n", mock_can_rx_drops("vcan0"));
	CHECK(counter("rx_queue_drops") == 0);
	CHECK(counter("direct_stalls") >= 1); /* counted: the other thread read for the stalled put */
	if (counter("direct_stalls") < 1)
		fprintf(stderr, "direct_stalls %lld after a put held 300 ms\n", counter("direct_stalls"));
	zn_node_stop();
}

static void *open_gate_once_stopping(void *arg)
{
	(void)arg;
	/* zn_node_stop withdraws the token first: from then on the node is stopping */
	for (int waited_ms = 0; waited_ms < WAIT_MS && mock_zenoh_has_token(TOKEN); waited_ms++)
		mock_zenoh_wait_puts(MOCK_MAX_PUTS, 1); /* a bounded 1 ms poll of the token */
	gate(0);
	return NULL;
}

/* Stop while a put is stalled: stop waits for the put (nothing reads for a stuck put while
 * stopping), then every frame read goes out, in order. */
static void test_stop_during_stalled_put(void)
{
	mock_reset();
	zn_node_config_t cfg = batching();
	CHECK(zn_node_init(&cfg) == ESP_OK);
	size_t frames = load_around_a_held_put(30, 40, 9000);
	pthread_t opener;
	CHECK(pthread_create(&opener, NULL, open_gate_once_stopping, NULL) == 0);
	zn_node_stop();
	pthread_join(opener, NULL);
	check_published_frames(frames, 9000, 1, WAIT_MS);
}

/* A put held while the load ends and its stretch runs out: once it returns, everything
 * queued meanwhile goes out, whether the held put was a period's end (all of the queue) or an
 * early full batch (the stretch's end, which would publish the rest, came during the put).
 * Small batches and a small port make both kinds of put frequent; each round holds the next. */
static void test_rest_after_a_held_put(void)
{
	mock_reset();
	mock_can_set_capacity("vcan0", 16); /* a drain every few ms: batches fill between period ends */
	zn_node_config_t cfg = batching();
	cfg.batch_max_frames = 4;
	CHECK(zn_node_init(&cfg) == ESP_OK);
	size_t frames = 0;
	for (int round = 0; round < 12; round++) {
		for (int i = 0; i < 5 + round; i++, frames++) { /* a stretch runs */
			inject(frames, 3000);
			pace_ms(1);
		}
		gate(1);
		while (!wait_held_ms(1)) { /* the next put is held, the load going on */
			inject(frames++, 3000);
			pace_ms(1);
		}
		for (int i = 0; i < 3; i++, frames++) {
			inject(frames, 3000);
			pace_ms(1);
		}
		pace_ms(5 * PERIOD_MS); /* the load's end, held long enough for its stretch to end */
		gate(0);
		check_published_frames(frames, 3000, 0, WAIT_MS);
	}
	zn_node_stop();
}

/* The bus lost while an early full batch's put is held: the period that would have published
 * the rest of the queue is cancelled by the loss, so the rest must go out once the put returns
 * (it used to wait in the queue for the next frame, or the stop: read, not published). */
static void test_rest_after_a_bus_lost_during_a_held_put(void)
{
	mock_reset();
	zn_node_config_t cfg = batching();
	cfg.publish_period_ms = 1000; /* the period does not end during the test */
	cfg.batch_max_frames = 4;
	CHECK(zn_node_init(&cfg) == ESP_OK);
	can_message_t m[6];
	memset(m, 0, sizeof(m));
	for (uint32_t i = 0; i < 6; i++)
		m[i] = (can_message_t){ .identifier = 0x100 + i, .data_length_code = 1, .data = { (uint8_t)i } };
	gate(1);
	mock_can_inject_burst("vcan0", m, 6, 7000); /* one drain: a full batch of 4 put at once, 2 queued */
	CHECK(wait_held() == 1);
	mock_can_lose("vcan0"); /* the other thread's next drain finds the bus gone and reopens it */
	CHECK(counter_reaches("can_reopens", 1));
	gate(0);
	CHECK(counter_reaches("published_frames", 6));
	if (counter("published_frames") != 6)
		fprintf(stderr, "published_frames %lld of 6, rx_queued %lld, after a bus lost during a put\n",
			counter("published_frames"), counter("rx_queued"));
	zn_node_stop();
}

/* A batch whose put fails: publish_errors says how many frames went with it, as the bench
 * reads it beside published_frames (it counted the sample: 1 for a batch of 3). */
static void test_failed_batch_counted_in_frames(void)
{
	mock_reset();
	zn_node_config_t cfg = batching();
	CHECK(zn_node_init(&cfg) == ESP_OK);
	can_message_t m[3];
	memset(m, 0, sizeof(m));
	for (uint32_t i = 0; i < 3; i++)
		m[i] = (can_message_t){ .identifier = 0x200 + i, .data_length_code = 1, .data = { (uint8_t)i } };
	pthread_mutex_lock(&gate_lock);
	failing = 1;
	pthread_mutex_unlock(&gate_lock);
	mock_can_inject_burst("vcan0", m, 3, 8000);
	CHECK(counter_reaches("can_rx_frames", 3));
	for (int waited_ms = 0; waited_ms < WAIT_MS && counter("publish_errors") == 0; waited_ms++)
		pace_ms(1);
	CHECK(counter("publish_errors") == 3 && counter("published_frames") == 0);
	if (counter("publish_errors") != 3)
		fprintf(stderr, "publish_errors %lld after a failed put of 3 frames\n", counter("publish_errors"));
	pthread_mutex_lock(&gate_lock);
	failing = 0;
	pthread_mutex_unlock(&gate_lock);
	zn_node_stop();
}

/* Immediate mode: the reader's own put held, the stats say how long it has run; once it
 * returns, no put runs. */
static void test_immediate_put_running_in_stats(void)
{
	mock_reset();
	zn_node_config_t cfg = batching();
	cfg.publish_period_ms = 0;
	CHECK(zn_node_init(&cfg) == ESP_OK);
	CHECK(counter("put_running_ms") == 0);
	gate(1);
	inject(0, 2000);
	CHECK(wait_held() == 1);
	pace_ms(60); /* the put held this long at least */
	CHECK(counter("put_running_ms") >= 50);
	gate(0);
	check_published_frames(1, 2000, 1, WAIT_MS);
	CHECK(counter_reaches("put_running_ms", 0));
	zn_node_stop();
}

int main(void)
{
	test_immediate_put_running_in_stats();
	test_rest_after_a_held_put();
	test_one_wakeup_per_period();
	test_stalled_put_keeps_reading();
	test_stop_during_stalled_put();
	test_rest_after_a_bus_lost_during_a_held_put();
	test_failed_batch_counted_in_frames();
	CHECK_DONE("test_turns");
}
