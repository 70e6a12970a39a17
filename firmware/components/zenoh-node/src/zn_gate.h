/* zn_gate.h - the gate a Zenoh callback passes so its owner can be freed under it.
 *
 * Undeclaring a subscriber or queryable need not wait for a callback already running (Zenoh
 * 1.10's default: the Linux port's subscribers wait, its queryable does not, since a reply can
 * block), and one may even start after it. The callback enters the gate before it touches
 * anything and leaves it when done; the owner shuts the gate, undeclares, then waits until none
 * is inside before freeing what callbacks read. A callback that finds the gate shut touches
 * nothing else but static storage (its count of refusals, beside the gate). The gate itself lives
 * in static storage, so it outlives every callback, and outside the node's state, whose resets
 * would open it. */
#ifndef ZN_GATE_H
#define ZN_GATE_H

#include <stdbool.h>

#include "zn_port_os.h"

struct zn_gate {
	int inside; /* atomics: callbacks inside; shut (no more may enter) */
	int shut;
};

/* Whether the caller may go on; if so it must call zn_gate_leave once done. */
bool zn_gate_enter(struct zn_gate *g);

/* Leaves; when lock and cond are given (both alive while the gate is open), wakes the owner
 * waiting in zn_gate_wait on them, else the owner sees it at its next re-read. */
void zn_gate_leave(struct zn_gate *g, zn_mutex_t *lock, zn_cond_t *cond);

void zn_gate_shut(struct zn_gate *g);

/* Lets callbacks in (again): once what they read exists. */
void zn_gate_open(struct zn_gate *g);

/* Until no callback is inside (the gate shut first); one turned away at the gate does not
 * signal, so the count is re-read every recheck_ms. Without a lock or cond there is nothing
 * to wait on: init failed before them, so before the callback was declared. */
void zn_gate_wait(struct zn_gate *g, zn_mutex_t *lock, zn_cond_t *cond, int recheck_ms);

#endif
