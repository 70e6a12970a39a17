/* zn_qos.h - the CAN -> Zenoh QoS table: Zenoh QoS chosen per CAN id range.
 *
 * Grammar (cfg.rx_qos_table, Kconfig ZENOH_RX_QOS, --rx-qos):
 *   table := rule { ";" rule }          ("" = no table: every frame has rx_qos)
 *   rule  := range ":" item { "," item }
 *   range := [ "e:" ] ID [ "-" ID ]     hex, optional 0x; e: = 29-bit ids (<= 0x1FFFFFFF),
 *                                       else 11-bit (<= 0x7FF), as --allow-ids
 *   item  := realtime | interactive-high | interactive-low | data-high | data | data-low
 *          | background                 (Zenoh's priorities, 1 .. 7)
 *          | express | best-effort | reliable | drop | block
 * A rule starts from rx_qos (--rx-priority, --rx-congestion, --rx-express;
 * reliable) and changes what it names. Example:
 *   0x000-0x0FF:realtime,express;0x100-0x7FF:data,best-effort;e:18DA0000-18DAFFFF:background,drop
 * Frames no rule names keep rx_qos. Ranges of one kind (11- or 29-bit) must not
 * overlap. Rules with equal QoS share a class; at most ZN_MAX_QOS_CLASSES
 * classes, the default one included. */
#ifndef ZN_QOS_H
#define ZN_QOS_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "driver/can.h"
#include "zn_port_zenoh.h"

#define ZN_MAX_QOS_CLASSES 8 /* a publisher and a queue each, per bus */
#define ZN_MAX_QOS_RULES 16

typedef struct {
	uint32_t first, last; /* inclusive */
	bool extended;
	uint8_t cls; /* index into classes */
} zn_qos_rule_t;

typedef struct {
	/* distinct QoS, highest Zenoh priority first (the order the publisher serves them);
	 * among equal priorities in the order the table names them, the default last */
	zn_qos_t classes[ZN_MAX_QOS_CLASSES];
	size_t class_count;	 /* >= 1 */
	uint8_t default_class;	 /* of frames no rule names: rx_qos */
	zn_qos_rule_t rules[ZN_MAX_QOS_RULES];
	size_t rule_count;
} zn_qos_table_t;

/* Parses text over the default QoS base into out; on error writes one line into err
 * and returns -1. */
int zn_qos_parse(const char *text, const zn_qos_t *base, zn_qos_table_t *out, char *err, size_t err_len);

/* The class of a frame. */
static inline uint8_t zn_qos_class_of(const zn_qos_table_t *t, const can_message_t *msg)
{
	for (size_t i = 0; i < t->rule_count; i++)
		if ((bool)msg->extd == t->rules[i].extended && msg->identifier >= t->rules[i].first &&
		    msg->identifier <= t->rules[i].last)
			return t->rules[i].cls;
	return t->default_class;
}

/* "realtime,express,block,reliable": a QoS in the table's words, for logs and stats. */
void zn_qos_describe(const zn_qos_t *q, char *buf, size_t cap);

#endif
