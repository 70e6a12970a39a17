/* zn_gate.c - the callback gate (zn_gate.h). Sequentially consistent atomics: a callback's
 * entry and the owner's shut must not both be missed by the other. */
#include "zn_gate.h"

bool zn_gate_enter(struct zn_gate *g)
{
	__atomic_add_fetch(&g->inside, 1, __ATOMIC_SEQ_CST);
	if (!__atomic_load_n(&g->shut, __ATOMIC_SEQ_CST))
		return true;
	__atomic_sub_fetch(&g->inside, 1, __ATOMIC_SEQ_CST);
	return false;
}

void zn_gate_leave(struct zn_gate *g, zn_mutex_t *lock, zn_cond_t *cond)
{
	if (!lock || !cond) {
		__atomic_sub_fetch(&g->inside, 1, __ATOMIC_SEQ_CST);
		return;
	}
	zn_mutex_lock(lock); /* under the owner's lock, so its wait cannot miss the signal */
	__atomic_sub_fetch(&g->inside, 1, __ATOMIC_SEQ_CST);
	zn_cond_signal(cond);
	zn_mutex_unlock(lock);
}

void zn_gate_shut(struct zn_gate *g)
{
	__atomic_store_n(&g->shut, 1, __ATOMIC_SEQ_CST);
}

void zn_gate_open(struct zn_gate *g)
{
	__atomic_store_n(&g->shut, 0, __ATOMIC_SEQ_CST);
}

void zn_gate_wait(struct zn_gate *g, zn_mutex_t *lock, zn_cond_t *cond, int recheck_ms)
{
	if (!lock || !cond)
		return;
	zn_mutex_lock(lock);
	while (__atomic_load_n(&g->inside, __ATOMIC_SEQ_CST) > 0)
		zn_cond_wait(cond, lock, recheck_ms);
	zn_mutex_unlock(lock);
}
