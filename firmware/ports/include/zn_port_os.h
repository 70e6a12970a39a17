/* zn_port_os.h - contract of the OS port: threads, clocks, locks. Linux:
 * ports/linux/os_linux.c (pthreads); ESP32 (planned): ports/esp32/os_freertos.c. */
#ifndef ZN_PORT_OS_H
#define ZN_PORT_OS_H

#include <stdint.h>

#include "esp_err.h"

typedef struct zn_thread zn_thread_t;
typedef struct zn_mutex zn_mutex_t;
typedef struct zn_cond zn_cond_t;

esp_err_t zn_thread_start(zn_thread_t **out, const char *name, void (*fn)(void *), void *arg);
void zn_thread_join(zn_thread_t *t);

esp_err_t zn_mutex_new(zn_mutex_t **out);
void zn_mutex_lock(zn_mutex_t *m);
void zn_mutex_unlock(zn_mutex_t *m);
void zn_mutex_free(zn_mutex_t *m);

esp_err_t zn_cond_new(zn_cond_t **out);
/* Waits until signalled or timeout_ms passes (-1 = forever); m held on entry and return. */
void zn_cond_wait(zn_cond_t *c, zn_mutex_t *m, int timeout_ms);
void zn_cond_signal(zn_cond_t *c);
void zn_cond_free(zn_cond_t *c);

int64_t zn_monotonic_ns(void);
int64_t zn_realtime_ns(void);
/* Writes a timestamped log line to the platform's log (stderr on Linux). */
void zn_log(const char *level, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

#endif
