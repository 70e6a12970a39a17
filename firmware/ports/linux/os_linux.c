/* os_linux.c - OS port over POSIX threads and clocks. */
#define _GNU_SOURCE
#include <errno.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "zn_port_os.h"

struct zn_thread {
	pthread_t tid;
	void (*fn)(void *);
	void *arg;
};
struct zn_mutex {
	pthread_mutex_t m;
};
struct zn_cond {
	pthread_cond_t c;
};

static void *trampoline(void *p)
{
	zn_thread_t *t = p;
	t->fn(t->arg);
	return NULL;
}

esp_err_t zn_thread_start(zn_thread_t **out, const char *name, void (*fn)(void *), void *arg)
{
	zn_thread_t *t = calloc(1, sizeof(*t));
	if (!t)
		return ESP_ERR_NO_MEM;
	t->fn = fn;
	t->arg = arg;
	if (pthread_create(&t->tid, NULL, trampoline, t) != 0) {
		free(t);
		return ESP_FAIL;
	}
	pthread_setname_np(t->tid, name);
	*out = t;
	return ESP_OK;
}

void zn_thread_join(zn_thread_t *t)
{
	if (!t)
		return;
	pthread_join(t->tid, NULL);
	free(t);
}

esp_err_t zn_mutex_new(zn_mutex_t **out)
{
	zn_mutex_t *m = calloc(1, sizeof(*m));
	if (!m)
		return ESP_ERR_NO_MEM;
	pthread_mutex_init(&m->m, NULL);
	*out = m;
	return ESP_OK;
}

void zn_mutex_lock(zn_mutex_t *m) { pthread_mutex_lock(&m->m); }
void zn_mutex_unlock(zn_mutex_t *m) { pthread_mutex_unlock(&m->m); }

void zn_mutex_free(zn_mutex_t *m)
{
	if (!m)
		return;
	pthread_mutex_destroy(&m->m);
	free(m);
}

esp_err_t zn_cond_new(zn_cond_t **out)
{
	zn_cond_t *c = calloc(1, sizeof(*c));
	if (!c)
		return ESP_ERR_NO_MEM;
	pthread_condattr_t attr;
	pthread_condattr_init(&attr);
	pthread_condattr_setclock(&attr, CLOCK_MONOTONIC);
	pthread_cond_init(&c->c, &attr);
	pthread_condattr_destroy(&attr);
	*out = c;
	return ESP_OK;
}

void zn_cond_wait(zn_cond_t *c, zn_mutex_t *m, int timeout_ms)
{
	if (timeout_ms < 0) {
		pthread_cond_wait(&c->c, &m->m);
		return;
	}
	struct timespec ts;
	clock_gettime(CLOCK_MONOTONIC, &ts);
	ts.tv_sec += timeout_ms / 1000;
	ts.tv_nsec += (long)(timeout_ms % 1000) * 1000000;
	if (ts.tv_nsec >= 1000000000) {
		ts.tv_sec++;
		ts.tv_nsec -= 1000000000;
	}
	pthread_cond_timedwait(&c->c, &m->m, &ts);
}

void zn_cond_signal(zn_cond_t *c) { pthread_cond_broadcast(&c->c); }

void zn_cond_free(zn_cond_t *c)
{
	if (!c)
		return;
	pthread_cond_destroy(&c->c);
	free(c);
}

static int64_t clock_ns(clockid_t id)
{
	struct timespec ts;
	clock_gettime(id, &ts);
	return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

int64_t zn_monotonic_ns(void) { return clock_ns(CLOCK_MONOTONIC); }
int64_t zn_realtime_ns(void) { return clock_ns(CLOCK_REALTIME); }

void zn_log(const char *level, const char *fmt, ...)
{
	char line[1024];
	struct timespec ts;
	struct tm tm;
	clock_gettime(CLOCK_REALTIME, &ts);
	gmtime_r(&ts.tv_sec, &tm);
	int n = snprintf(line, sizeof(line), "%02d:%02d:%02d.%03ld %s zenoh-node: ", tm.tm_hour, tm.tm_min, tm.tm_sec,
			 ts.tv_nsec / 1000000, level);
	if (n < 0 || (size_t)n >= sizeof(line))
		return;
	va_list ap, again;
	va_start(ap, fmt);
	va_copy(again, ap);
	int m = vsnprintf(line + n, sizeof(line) - (size_t)n, fmt, ap);
	va_end(ap);
	char *big = NULL; /* a long line (the final stats of many buses) is printed whole, not cut */
	if (m > 0 && (size_t)(n + m) >= sizeof(line) && (big = malloc((size_t)n + (size_t)m + 2))) {
		memcpy(big, line, (size_t)n);
		vsnprintf(big + n, (size_t)m + 1, fmt, again);
		big[n + m] = '\n';
		/* one write(2), not stdio (which writes an unbuffered stream through an 8 KiB buffer) */
		for (size_t off = 0, len = (size_t)n + (size_t)m + 1; off < len;) {
			ssize_t w = write(2, big + off, len - off);
			if (w < 0 && errno == EINTR)
				continue;
			if (w <= 0)
				break;
			off += (size_t)w;
		}
	}
	va_end(again);
	if (!big)
		fprintf(stderr, "%s\n", line); /* one write per line: lines from threads never interleave */
	free(big);
}
