/* can_mock.c - in-memory CAN port: frames injected by tests are received,
 * transmitted frames are recorded per bus. */
#include <pthread.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "zn_mock.h"
#include "zn_port_can.h"

#define MOCK_BUSES 8
#define MOCK_FRAMES 65536

struct mock_bus {
	char name[64];
	can_message_t rx[MOCK_FRAMES];
	int64_t rx_time[MOCK_FRAMES];
	size_t rx_head, rx_len;
	can_message_t tx[MOCK_FRAMES];
	pthread_t tx_thread[MOCK_FRAMES]; /* who transmitted each */
	size_t tx_len;
	int stalled;
	int tx_limited; /* the bus takes tx_room more frames, then holds the rest until given room */
	size_t tx_room;
	unsigned generation; /* handles of an older generation are of a bus that went away */
	size_t capacity;     /* frames held before injected ones are dropped (0: MOCK_FRAMES) */
	size_t rx_drops, reads, tx_calls; /* frames dropped; receive and transmit calls that moved frames */
	size_t tx_empty;		  /* transmit calls with a timeout of 0 that moved none */
	size_t rx_waiting;		  /* receive calls waiting for a frame now */
	size_t tx_held;			  /* burst sends waiting for the bus now */
	unsigned stalls_ended;		  /* mock_can_stall_ends: a send waiting since before one fails */
};

struct zn_can {
	struct mock_bus *bus;
	unsigned generation;
};

static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static pthread_cond_t arrived = PTHREAD_COND_INITIALIZER;
static pthread_cond_t sent = PTHREAD_COND_INITIALIZER; /* a frame transmitted, or a stall lifted */
static struct mock_bus *buses[MOCK_BUSES];

static struct mock_bus *find_bus(const char *name, int create)
{
	for (int i = 0; i < MOCK_BUSES; i++) {
		if (buses[i] && strcmp(buses[i]->name, name) == 0)
			return buses[i];
		if (!buses[i] && create) {
			buses[i] = calloc(1, sizeof(*buses[i]));
			strncpy(buses[i]->name, name, sizeof(buses[i]->name) - 1);
			return buses[i];
		}
	}
	return NULL;
}

static void record_tx(struct mock_bus *b, const can_message_t *msg) /* lock held */
{
	if (b->tx_len < MOCK_FRAMES) {
		b->tx_thread[b->tx_len] = pthread_self();
		b->tx[b->tx_len++] = *msg;
	}
	if (b->tx_limited)
		b->tx_room--;
}

void mock_can_reset(void);
void mock_can_reset(void)
{
	pthread_mutex_lock(&lock);
	for (int i = 0; i < MOCK_BUSES; i++) {
		free(buses[i]);
		buses[i] = NULL;
	}
	pthread_mutex_unlock(&lock);
}

static void inject_locked(struct mock_bus *b, const can_message_t *msg, int64_t rx_time_ns)
{
	size_t cap = b->capacity ? b->capacity : MOCK_FRAMES;
	if (b->rx_len < cap) {
		size_t at = (b->rx_head + b->rx_len++) % MOCK_FRAMES;
		b->rx[at] = *msg;
		b->rx_time[at] = rx_time_ns;
	} else {
		b->rx_drops++;
	}
}

void mock_can_inject(const char *bus, const can_message_t *msg, int64_t rx_time_ns)
{
	pthread_mutex_lock(&lock);
	inject_locked(find_bus(bus, 1), msg, rx_time_ns);
	pthread_cond_broadcast(&arrived);
	pthread_mutex_unlock(&lock);
}

void mock_can_inject_burst(const char *bus, const can_message_t *msgs, size_t n, int64_t first_rx_time_ns)
{
	pthread_mutex_lock(&lock);
	struct mock_bus *b = find_bus(bus, 1);
	for (size_t i = 0; i < n; i++)
		inject_locked(b, &msgs[i], first_rx_time_ns + (int64_t)i);
	pthread_cond_broadcast(&arrived);
	pthread_mutex_unlock(&lock);
}

void mock_can_set_capacity(const char *bus, size_t frames)
{
	pthread_mutex_lock(&lock);
	find_bus(bus, 1)->capacity = frames < MOCK_FRAMES ? frames : MOCK_FRAMES;
	pthread_mutex_unlock(&lock);
}

static size_t read_counter(const char *bus, size_t offset)
{
	pthread_mutex_lock(&lock);
	struct mock_bus *b = find_bus(bus, 0);
	size_t n = b ? *(size_t *)((char *)b + offset) : 0;
	pthread_mutex_unlock(&lock);
	return n;
}

size_t mock_can_rx_drops(const char *bus)
{
	return read_counter(bus, offsetof(struct mock_bus, rx_drops));
}

size_t mock_can_reads(const char *bus)
{
	return read_counter(bus, offsetof(struct mock_bus, reads));
}

size_t mock_can_tx_calls(const char *bus)
{
	return read_counter(bus, offsetof(struct mock_bus, tx_calls));
}

size_t mock_can_tx_count(const char *bus)
{
	pthread_mutex_lock(&lock);
	struct mock_bus *b = find_bus(bus, 0);
	size_t n = b ? b->tx_len : 0;
	pthread_mutex_unlock(&lock);
	return n;
}

/* Waits until a bus's counter (a size_t at offset) reaches n or timeout_ms passes; returns it. */
static size_t wait_counter(const char *bus, size_t offset, size_t n, int timeout_ms)
{
	struct timespec ts = mock_deadline(timeout_ms);
	pthread_mutex_lock(&lock);
	size_t *counter = (size_t *)((char *)find_bus(bus, 1) + offset);
	while (*counter < n && pthread_cond_timedwait(&sent, &lock, &ts) == 0)
		;
	size_t got = *counter;
	pthread_mutex_unlock(&lock);
	return got;
}

size_t mock_can_wait_tx(const char *bus, size_t n, int timeout_ms)
{
	return wait_counter(bus, offsetof(struct mock_bus, tx_len), n, timeout_ms);
}

size_t mock_can_wait_tx_empty(const char *bus, size_t n, int timeout_ms)
{
	return wait_counter(bus, offsetof(struct mock_bus, tx_empty), n, timeout_ms);
}

int mock_can_wait_receiving(const char *bus, int timeout_ms)
{
	return wait_counter(bus, offsetof(struct mock_bus, rx_waiting), 1, timeout_ms) > 0;
}

void mock_can_stall(const char *bus, int stalled)
{
	pthread_mutex_lock(&lock);
	find_bus(bus, 1)->stalled = stalled;
	pthread_cond_broadcast(&sent);
	pthread_mutex_unlock(&lock);
}

size_t mock_can_wait_tx_held(const char *bus, size_t n, int timeout_ms)
{
	return wait_counter(bus, offsetof(struct mock_bus, tx_held), n, timeout_ms);
}

size_t mock_can_stall_ends(const char *bus)
{
	pthread_mutex_lock(&lock);
	struct mock_bus *b = find_bus(bus, 1);
	size_t failed = b->tx_held;
	b->stalls_ended++;
	b->stalled = 0;
	b->tx_limited = 0;
	pthread_cond_broadcast(&sent);
	pthread_mutex_unlock(&lock);
	return failed;
}

void mock_can_tx_room(const char *bus, long frames)
{
	pthread_mutex_lock(&lock);
	struct mock_bus *b = find_bus(bus, 1);
	b->tx_limited = frames >= 0;
	b->tx_room = frames >= 0 ? (size_t)frames : 0;
	pthread_cond_broadcast(&sent);
	pthread_mutex_unlock(&lock);
}

int mock_can_tx_by(const char *bus, size_t i, pthread_t thread)
{
	pthread_mutex_lock(&lock);
	struct mock_bus *b = find_bus(bus, 0);
	int by = b && i < b->tx_len && i < MOCK_FRAMES && pthread_equal(b->tx_thread[i], thread);
	pthread_mutex_unlock(&lock);
	return by;
}

void mock_can_lose(const char *bus)
{
	pthread_mutex_lock(&lock);
	find_bus(bus, 1)->generation++;
	pthread_cond_broadcast(&arrived);
	pthread_cond_broadcast(&sent);
	pthread_mutex_unlock(&lock);
}

can_message_t mock_can_tx(const char *bus, size_t i)
{
	can_message_t m;
	memset(&m, 0, sizeof(m));
	pthread_mutex_lock(&lock);
	struct mock_bus *b = find_bus(bus, 0);
	if (b && i < b->tx_len)
		m = b->tx[i];
	pthread_mutex_unlock(&lock);
	return m;
}

esp_err_t zn_can_open(const char *name, zn_can_t **out)
{
	zn_can_t *c = calloc(1, sizeof(*c));
	pthread_mutex_lock(&lock);
	c->bus = find_bus(name, 1);
	c->generation = c->bus->generation;
	pthread_mutex_unlock(&lock);
	*out = c;
	return ESP_OK;
}

/* With the lock held: waits until the handle's bus has a frame queued (ESP_OK), the bus was
 * reopened behind the handle (ESP_FAIL) or the deadline passed (ESP_ERR_TIMEOUT; at once with
 * no_wait). Returns with the lock held. */
static esp_err_t wait_rx(zn_can_t *can, const struct timespec *deadline, int no_wait)
{
	struct mock_bus *b = can->bus;
	while (b->rx_len == 0 || can->generation != b->generation) {
		if (can->generation != b->generation)
			return ESP_FAIL;
		if (no_wait)
			return ESP_ERR_TIMEOUT;
		b->rx_waiting++;
		pthread_cond_broadcast(&sent); /* mock_can_wait_receiving */
		int rc = pthread_cond_timedwait(&arrived, &lock, deadline);
		b->rx_waiting--;
		if (rc != 0)
			return ESP_ERR_TIMEOUT;
	}
	return ESP_OK;
}

esp_err_t zn_can_receive(zn_can_t *can, can_message_t *msg, int64_t *rx_time_ns, int timeout_ms)
{
	struct timespec ts = mock_deadline(timeout_ms);
	pthread_mutex_lock(&lock);
	esp_err_t err = wait_rx(can, &ts, 0);
	if (err != ESP_OK) {
		pthread_mutex_unlock(&lock);
		return err;
	}
	struct mock_bus *b = can->bus;
	*msg = b->rx[b->rx_head];
	*rx_time_ns = b->rx_time[b->rx_head];
	b->rx_head = (b->rx_head + 1) % MOCK_FRAMES;
	b->rx_len--;
	b->reads++;
	pthread_mutex_unlock(&lock);
	return ESP_OK;
}

esp_err_t zn_can_receive_burst(zn_can_t *can, zn_can_rx_t *out, size_t max, size_t *count, int timeout_ms)
{
	*count = 0;
	if (max == 0)
		return ESP_ERR_INVALID_ARG;
	if (max > ZN_CAN_BURST_MAX)
		max = ZN_CAN_BURST_MAX;
	struct timespec ts = mock_deadline(timeout_ms);
	pthread_mutex_lock(&lock);
	esp_err_t err = wait_rx(can, &ts, timeout_ms == 0);
	if (err != ESP_OK) {
		pthread_mutex_unlock(&lock);
		return err;
	}
	struct mock_bus *b = can->bus;
	while (*count < max && b->rx_len) {
		out[*count].msg = b->rx[b->rx_head];
		out[*count].rx_time_ns = b->rx_time[b->rx_head];
		(*count)++;
		b->rx_head = (b->rx_head + 1) % MOCK_FRAMES;
		b->rx_len--;
	}
	b->reads++;
	pthread_mutex_unlock(&lock);
	return ESP_OK;
}

size_t zn_can_rx_capacity(zn_can_t *can)
{
	pthread_mutex_lock(&lock);
	size_t cap = can->bus->capacity ? can->bus->capacity : MOCK_FRAMES;
	pthread_mutex_unlock(&lock);
	return cap;
}

esp_err_t zn_can_transmit(zn_can_t *can, const can_message_t *msg, int timeout_ms)
{
	struct timespec ts = mock_deadline(timeout_ms);
	pthread_mutex_lock(&lock);
	if (can->generation != can->bus->generation) {
		pthread_mutex_unlock(&lock);
		return ESP_FAIL;
	}
	while (can->bus->stalled || (can->bus->tx_limited && can->bus->tx_room == 0))
		if ((can->bus->stalled == MOCK_HOLD || !can->bus->stalled) && timeout_ms != 0) /* held, or no room */
			pthread_cond_wait(&sent, &lock);
		else if (timeout_ms == 0 || pthread_cond_timedwait(&sent, &lock, &ts) != 0) {
			pthread_mutex_unlock(&lock);
			return ESP_ERR_TIMEOUT;
		}
	record_tx(can->bus, msg);
	can->bus->tx_calls++;
	pthread_cond_broadcast(&sent);
	pthread_mutex_unlock(&lock);
	return ESP_OK;
}

esp_err_t zn_can_send_burst(zn_can_t *can, const can_message_t *msgs, size_t n, size_t *done, int timeout_ms)
{
	struct timespec ts = mock_deadline(timeout_ms);
	esp_err_t rc = ESP_OK;
	int held = 0; /* counted in tx_held (once a call: a broadcast each wait would wake other held sends in turn) */
	*done = 0;
	pthread_mutex_lock(&lock);
	struct mock_bus *b = can->bus;
	unsigned stalls_ended = b->stalls_ended;
	for (;;) {
		if (can->generation != b->generation) {
			rc = ESP_FAIL;
			break;
		}
		if (b->stalls_ended != stalls_ended) { /* the stall outlasted this send's wait */
			rc = ESP_ERR_TIMEOUT;
			break;
		}
		if (!b->stalled) {
			size_t before = *done;
			for (; *done < n && (!b->tx_limited || b->tx_room > 0); (*done)++)
				record_tx(b, &msgs[*done]);
			if (*done > before) {
				b->tx_calls += before == 0; /* a call that moved frames, counted once */
				pthread_cond_broadcast(&sent);
			}
			if (*done == n)
				break;
		}
		if (timeout_ms == 0) {
			if (*done == 0) {
				b->tx_empty++;
				pthread_cond_broadcast(&sent);
			}
			rc = ESP_ERR_TIMEOUT;
			break;
		}
		if (!held) {
			held = 1;
			b->tx_held++;
			pthread_cond_broadcast(&sent); /* mock_can_wait_tx_held */
		}
		if (b->stalled == MOCK_HOLD || !b->stalled) /* held, or no room */
			pthread_cond_wait(&sent, &lock);
		else if (pthread_cond_timedwait(&sent, &lock, &ts) != 0) {
			rc = ESP_ERR_TIMEOUT;
			break;
		}
	}
	b->tx_held -= (size_t)held;
	pthread_mutex_unlock(&lock);
	return rc;
}

void zn_can_close(zn_can_t *can)
{
	free(can);
}
