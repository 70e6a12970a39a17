/* zenoh_mock.c - recording Zenoh port: puts are stored, samples can be
 * delivered to subscribers, tokens and queryables are looked up by key. */
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "zn_mock.h"
#include "zn_port_zenoh.h"

#define MOCK_DECLS 64

struct zn_session {
	int open;
};
struct zn_publisher {
	char key[256];
	int index; /* into pubs_log */
};
struct zn_subscriber {
	char key[256];
	zn_sample_cb cb;
	void *ctx;
};
struct zn_token {
	char key[256];
};
struct zn_queryable {
	char key[256];
	zn_query_cb cb;
	void *ctx;
};

static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static pthread_cond_t put_made = PTHREAD_COND_INITIALIZER;
static struct mock_put *puts_log;
static size_t nputs;
static struct mock_publisher pubs_log[MOCK_DECLS];
static size_t npubs;
static struct zn_subscriber *subs[MOCK_DECLS];
static struct zn_token *tokens[MOCK_DECLS];
static struct zn_queryable *queryables[MOCK_DECLS];
static int open_result;
static uint64_t connections_closed;
static int unrouted;
static zn_session_config_t last_open;

void mock_can_reset(void);

/* mock_zenoh_deliver_on_declare's command, for the next subscriber of its key (empty key: none) */
static struct {
	char key[128];
	uint8_t payload[64];
	size_t len;
} on_declare;

/* the batch this thread's puts are held in (0: none), numbered from 1 since mock_reset */
static __thread unsigned held_batch;
static unsigned batches, batch_misuse;

void mock_reset(void)
{
	pthread_mutex_lock(&lock);
	nputs = 0;
	npubs = 0;
	if (!puts_log)
		puts_log = calloc(MOCK_MAX_PUTS, sizeof(*puts_log));
	memset(subs, 0, sizeof(subs));
	memset(tokens, 0, sizeof(tokens));
	memset(queryables, 0, sizeof(queryables));
	open_result = 0;
	on_declare.key[0] = 0;
	__atomic_store_n(&connections_closed, 0, __ATOMIC_RELAXED);
	unrouted = 0;
	batches = batch_misuse = 0;
	pthread_mutex_unlock(&lock);
	mock_can_reset();
}

static void add(void **table, void *item)
{
	for (int i = 0; i < MOCK_DECLS; i++)
		if (!table[i]) {
			table[i] = item;
			return;
		}
}

static void drop(void **table, void *item)
{
	for (int i = 0; i < MOCK_DECLS; i++)
		if (table[i] == item)
			table[i] = NULL;
}

void mock_zenoh_open_result(int rc)
{
	open_result = rc;
}

zn_session_config_t mock_zenoh_last_open(void)
{
	return last_open;
}

int zn_open(const zn_session_config_t *config, zn_session_t **out)
{
	last_open = *config;
	if (open_result)
		return open_result;
	*out = calloc(1, sizeof(**out));
	return 0;
}

int zn_declare_publisher(zn_session_t *s, const char *key, const zn_qos_t *qos, zn_publisher_t **out)
{
	(void)s;
	*out = calloc(1, sizeof(**out));
	strncpy((*out)->key, key, sizeof((*out)->key) - 1);
	pthread_mutex_lock(&lock);
	(*out)->index = (int)npubs;
	if (npubs < MOCK_DECLS) {
		memcpy(pubs_log[npubs].key, (*out)->key, sizeof(pubs_log[npubs].key));
		pubs_log[npubs++].qos = *qos;
	}
	pthread_mutex_unlock(&lock);
	return 0;
}

int zn_put(zn_publisher_t *pub, const uint8_t *payload, size_t len, const uint8_t *attachment, size_t attachment_len)
{
	if (len > MOCK_PAYLOAD_MAX || attachment_len > MOCK_ATTACHMENT_MAX)
		return -1;
	pthread_mutex_lock(&lock);
	if (nputs < MOCK_MAX_PUTS) {
		struct mock_put *p = &puts_log[nputs++];
		memcpy(p->key, pub->key, sizeof(p->key));
		memcpy(p->payload, payload, len);
		p->len = len;
		if (attachment)
			memcpy(p->attachment, attachment, attachment_len);
		p->attachment_len = attachment_len;
		p->publisher = pub->index;
		p->batch = held_batch;
	}
	pthread_cond_broadcast(&put_made);
	int rc = unrouted ? ZN_PORT_UNROUTED : 0;
	pthread_mutex_unlock(&lock);
	return rc;
}

void mock_zenoh_deliver_on_declare(const char *key, const uint8_t *payload, size_t len)
{
	pthread_mutex_lock(&lock);
	snprintf(on_declare.key, sizeof(on_declare.key), "%s", key);
	on_declare.len = len < sizeof(on_declare.payload) ? len : sizeof(on_declare.payload);
	memcpy(on_declare.payload, payload, on_declare.len);
	pthread_mutex_unlock(&lock);
}

int zn_declare_subscriber(zn_session_t *s, const char *key, zn_sample_cb cb, void *ctx, zn_subscriber_t **out)
{
	(void)s;
	zn_subscriber_t *sub = calloc(1, sizeof(*sub));
	strncpy(sub->key, key, sizeof(sub->key) - 1);
	sub->cb = cb;
	sub->ctx = ctx;
	uint8_t payload[sizeof(on_declare.payload)];
	size_t len = 0;
	int now = 0;
	pthread_mutex_lock(&lock);
	add((void **)subs, sub);
	if (on_declare.key[0] && strcmp(on_declare.key, key) == 0) {
		now = 1;
		len = on_declare.len;
		memcpy(payload, on_declare.payload, len);
		on_declare.key[0] = 0;
	}
	pthread_mutex_unlock(&lock);
	if (now)
		cb(payload, len, NULL, 0, 0, ctx);
	*out = sub;
	return 0;
}

int zn_declare_token(zn_session_t *s, const char *key, zn_token_t **out)
{
	(void)s;
	zn_token_t *t = calloc(1, sizeof(*t));
	strncpy(t->key, key, sizeof(t->key) - 1);
	pthread_mutex_lock(&lock);
	add((void **)tokens, t);
	pthread_mutex_unlock(&lock);
	*out = t;
	return 0;
}

int zn_declare_queryable(zn_session_t *s, const char *key, zn_query_cb cb, void *ctx, zn_queryable_t **out)
{
	(void)s;
	zn_queryable_t *q = calloc(1, sizeof(*q));
	strncpy(q->key, key, sizeof(q->key) - 1);
	q->cb = cb;
	q->ctx = ctx;
	pthread_mutex_lock(&lock);
	add((void **)queryables, q);
	pthread_mutex_unlock(&lock);
	*out = q;
	return 0;
}

int zn_routers(zn_session_t *s, char *ids, size_t cap)
{
	(void)s;
	strncpy(ids, "mockrouter", cap);
	return 1;
}

void zn_batch_start(zn_session_t *s)
{
	(void)s;
	pthread_mutex_lock(&lock);
	if (held_batch)
		batch_misuse++; /* nested */
	held_batch = ++batches;
	pthread_mutex_unlock(&lock);
}

void zn_batch_stop(zn_session_t *s)
{
	(void)s;
	pthread_mutex_lock(&lock);
	if (!held_batch)
		batch_misuse++; /* no start */
	held_batch = 0;
	pthread_mutex_unlock(&lock);
}

unsigned mock_zenoh_batch_misuse(void)
{
	pthread_mutex_lock(&lock);
	unsigned n = batch_misuse;
	pthread_mutex_unlock(&lock);
	return n;
}

void zn_poll_connections(zn_session_t *s)
{
	(void)s; /* the mock's connection set is mock_zenoh_unrouted */
}

void mock_zenoh_unrouted(int on)
{
	pthread_mutex_lock(&lock);
	unrouted = on;
	pthread_mutex_unlock(&lock);
}

void mock_zenoh_close_connection(void)
{
	__atomic_add_fetch(&connections_closed, 1, __ATOMIC_RELAXED);
}

uint64_t zn_connections_closed(zn_session_t *s)
{
	(void)s;
	return __atomic_load_n(&connections_closed, __ATOMIC_RELAXED);
}

int zn_session_id(zn_session_t *s, char *buf, size_t cap)
{
	(void)s;
	strncpy(buf, "mock", cap);
	return 0;
}

void zn_undeclare_publisher(zn_publisher_t *pub)
{
	free(pub);
}

void zn_undeclare_subscriber(zn_subscriber_t *sub)
{
	pthread_mutex_lock(&lock);
	drop((void **)subs, sub);
	pthread_mutex_unlock(&lock);
	free(sub);
}

void zn_undeclare_token(zn_token_t *token)
{
	pthread_mutex_lock(&lock);
	drop((void **)tokens, token);
	pthread_mutex_unlock(&lock);
	free(token);
}

void zn_undeclare_queryable(zn_queryable_t *q)
{
	pthread_mutex_lock(&lock);
	drop((void **)queryables, q);
	pthread_mutex_unlock(&lock);
	free(q);
}

void zn_close(zn_session_t *s)
{
	free(s);
}

/* A log's length, read under the lock its writers hold. */
static size_t locked_count(const size_t *count)
{
	pthread_mutex_lock(&lock);
	size_t n = *count;
	pthread_mutex_unlock(&lock);
	return n;
}

size_t mock_zenoh_put_count(void)
{
	return locked_count(&nputs);
}

const struct mock_put *mock_zenoh_put(size_t i)
{
	return i < mock_zenoh_put_count() ? &puts_log[i] : NULL;
}

size_t mock_zenoh_wait_puts(size_t n, int timeout_ms)
{
	struct timespec ts = mock_deadline(timeout_ms);
	pthread_mutex_lock(&lock);
	while (nputs < n && pthread_cond_timedwait(&put_made, &lock, &ts) == 0)
		;
	size_t got = nputs;
	pthread_mutex_unlock(&lock);
	return got;
}

int mock_zenoh_deliver(const char *key, const uint8_t *payload, size_t len, const uint8_t *attachment,
		       size_t attachment_len)
{
	return mock_zenoh_deliver_at(key, payload, len, attachment, attachment_len, 0);
}

int mock_zenoh_deliver_at(const char *key, const uint8_t *payload, size_t len, const uint8_t *attachment,
			  size_t attachment_len, uint64_t source_time_ns)
{
	zn_sample_cb cb = NULL;
	void *ctx = NULL;
	pthread_mutex_lock(&lock);
	for (int i = 0; i < MOCK_DECLS; i++)
		if (subs[i] && strcmp(subs[i]->key, key) == 0) {
			cb = subs[i]->cb;
			ctx = subs[i]->ctx;
		}
	pthread_mutex_unlock(&lock);
	if (!cb)
		return -1;
	cb(payload, len, attachment, attachment_len, source_time_ns, ctx);
	return 0;
}

int mock_zenoh_has_token(const char *key)
{
	int found = 0;
	pthread_mutex_lock(&lock);
	for (int i = 0; i < MOCK_DECLS; i++)
		found |= tokens[i] && strcmp(tokens[i]->key, key) == 0;
	pthread_mutex_unlock(&lock);
	return found;
}

size_t mock_zenoh_query(const char *key, char *buf, size_t cap)
{
	zn_query_cb cb = NULL;
	void *ctx = NULL;
	pthread_mutex_lock(&lock);
	for (int i = 0; i < MOCK_DECLS; i++)
		if (queryables[i] && strcmp(queryables[i]->key, key) == 0) {
			cb = queryables[i]->cb;
			ctx = queryables[i]->ctx;
		}
	pthread_mutex_unlock(&lock);
	size_t n = cb ? cb(buf, cap, ctx) : cap; /* none answers: as a reply that did not fit */
	if (n >= cap) { /* did not fit (zn_query_cb's contract): "" as a port that gave up */
		if (cap)
			buf[0] = '\0';
		return 0;
	}
	return n;
}

size_t mock_zenoh_publisher_count(void)
{
	return locked_count(&npubs);
}

const struct mock_publisher *mock_zenoh_publisher(size_t i)
{
	return i < mock_zenoh_publisher_count() ? &pubs_log[i] : NULL;
}
