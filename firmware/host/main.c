/* zenoh-node (Linux) - runs the zenoh-node component as a process.
 *
 * Every Kconfig option has an environment variable of the same name and a
 * flag; precedence: Kconfig default < environment < flag. Invalid
 * configuration: one line on stderr, exit code 2. SIGTERM/SIGINT: flush the
 * pending batch, undeclare, close, print final stats, exit 0 (also while
 * still waiting for the router, when there is nothing to flush yet).
 *
 * Example: zenoh-node --can vcan0 --router tcp/127.0.0.1:7447 --publish-period-ms 0 */
#define _GNU_SOURCE
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <unistd.h>

#include "zn_node.h"
#include "zn_config_parse.h"

static pthread_mutex_t state_lock = PTHREAD_MUTEX_INITIALIZER;
static pthread_cond_t state_changed = PTHREAD_COND_INITIALIZER;
static int running, stop_requested;

/* All threads block SIGTERM/SIGINT; this one takes them. */
static void *signal_thread(void *arg)
{
	sigset_t *mask = arg;
	int sig;
	sigwait(mask, &sig);
	pthread_mutex_lock(&state_lock);
	if (!running) {
		fprintf(stderr, "zenoh-node: stopping before the bridge was up\n");
		_exit(0);
	}
	stop_requested = 1;
	pthread_cond_broadcast(&state_changed);
	pthread_mutex_unlock(&state_lock);
	return NULL;
}

int main(int argc, char **argv)
{
	zn_node_config_t cfg;
	char err[256];
	int rc = zn_config_from_env_and_args(&cfg, argc, argv, err, sizeof(err));
	if (rc == ZN_CONFIG_HELP) {
		zn_config_usage(stdout);
		return 0;
	}
	if (rc != ZN_CONFIG_OK) {
		fprintf(stderr, "zenoh-node: %s\n", err);
		return 2;
	}
	if (!cfg.enabled) {
		fprintf(stderr, "zenoh-node: disabled (ZENOH_NODE_ENABLED=0); exiting\n");
		return 0;
	}
	static sigset_t mask;
	sigemptyset(&mask);
	sigaddset(&mask, SIGTERM);
	sigaddset(&mask, SIGINT);
	pthread_sigmask(SIG_BLOCK, &mask, NULL); /* inherited by every thread started from here */
	pthread_t sig_tid;
	if (pthread_create(&sig_tid, NULL, signal_thread, &mask) != 0) {
		fprintf(stderr, "zenoh-node: cannot start the signal thread\n");
		return 1;
	}
	esp_err_t init = zn_node_init(&cfg);
	if (init != ESP_OK) {
		zn_node_stop();
		return init == ESP_ERR_INVALID_ARG ? 2 : 1;
	}
	pthread_mutex_lock(&state_lock);
	running = 1;
	while (!stop_requested)
		pthread_cond_wait(&state_changed, &state_lock);
	pthread_mutex_unlock(&state_lock);
	fprintf(stderr, "zenoh-node: stopping\n");
	zn_node_stop();
	return 0;
}
