/* zn_qos.c - the CAN -> Zenoh QoS table (grammar and example: zn_qos.h):
 * parsing with one line per problem, and the names of a QoS. */
#include <inttypes.h>
#include <stdio.h>
#include <string.h>

#include "zn_qos.h"

static const char *const priority_names[8] = { NULL, "realtime", "interactive-high", "interactive-low", "data-high",
					       "data", "data-low", "background" };

#define PRIORITY_LIST "realtime, interactive-high, interactive-low, data-high, data, data-low, background"
#define FLAG_LIST "express, best-effort, reliable, drop, block"

/* A QoS with the items a rule set (a rule names each field at most once). */
enum { SET_PRIORITY = 1, SET_EXPRESS = 2, SET_RELIABILITY = 4, SET_CONGESTION = 8 };

static int qos_equal(const zn_qos_t *a, const zn_qos_t *b)
{
	return a->priority == b->priority && a->congestion == b->congestion && a->express == b->express &&
	       a->best_effort == b->best_effort;
}

static void trim(const char **s, size_t *n)
{
	while (*n && (**s == ' ' || **s == '\t'))
		(*s)++, (*n)--;
	while (*n && ((*s)[*n - 1] == ' ' || (*s)[*n - 1] == '\t'))
		(*n)--;
}

static int word_is(const char *s, size_t n, const char *word)
{
	return n == strlen(word) && memcmp(s, word, n) == 0;
}

/* One hex id of s[0..n): optional 0x, at most 8 digits. */
static int parse_id(const char *s, size_t n, uint32_t *out)
{
	if (n > 2 && s[0] == '0' && (s[1] == 'x' || s[1] == 'X'))
		s += 2, n -= 2;
	if (n == 0 || n > 8)
		return -1;
	uint32_t v = 0;
	for (size_t i = 0; i < n; i++) {
		char c = s[i];
		int d = c >= '0' && c <= '9' ? c - '0' : c >= 'a' && c <= 'f' ? c - 'a' + 10 : c >= 'A' && c <= 'F' ? c - 'A' + 10 : -1;
		if (d < 0)
			return -1;
		v = v << 4 | (uint32_t)d;
	}
	*out = v;
	return 0;
}

#define FAIL(...)                                                                                                      \
	do {                                                                                                           \
		snprintf(err, err_len, "rx QoS table: " __VA_ARGS__);                                                 \
		return -1;                                                                                             \
	} while (0)

static int parse_range(const char *s, size_t n, zn_qos_rule_t *r, char *err, size_t err_len)
{
	const char *text = s;
	size_t text_n = n;
	r->extended = n >= 2 && s[0] == 'e' && s[1] == ':';
	if (r->extended)
		s += 2, n -= 2;
	const char *dash = memchr(s, '-', n);
	size_t first_n = dash ? (size_t)(dash - s) : n;
	const char *last_s = dash ? dash + 1 : s;
	size_t last_n = dash ? n - first_n - 1 : n;
	trim(&s, &first_n);
	trim(&last_s, &last_n);
	if (parse_id(s, first_n, &r->first) != 0 || parse_id(last_s, last_n, &r->last) != 0)
		FAIL("id range '%.*s' is not HEX or HEX-HEX (prefix e: for 29-bit ids)", (int)text_n, text);
	uint32_t max = r->extended ? CAN_EXTD_ID_MASK : CAN_STD_ID_MASK;
	if (r->last > max || r->first > max)
		FAIL("id range '%.*s' is beyond 0x%" PRIX32 " (%s)", (int)text_n, text, max,
		     r->extended ? "29 bits" : "11 bits; prefix e: for 29-bit ids");
	if (r->first > r->last)
		FAIL("id range '%.*s' is empty (first above last)", (int)text_n, text);
	return 0;
}

/* The items of one rule over base. */
static int parse_items(const char *s, size_t n, const zn_qos_t *base, zn_qos_t *q, char *err, size_t err_len)
{
	*q = *base;
	q->best_effort = base->best_effort;
	unsigned set = 0;
	while (n) {
		const char *comma = memchr(s, ',', n);
		size_t len = comma ? (size_t)(comma - s) : n;
		const char *w = s;
		size_t wn = len;
		trim(&w, &wn);
		unsigned field = 0;
		if (wn == 0)
			FAIL("an empty QoS item in '%.*s'", (int)n, s);
		for (uint8_t p = 1; p <= 7; p++)
			if (word_is(w, wn, priority_names[p])) {
				q->priority = p;
				field = SET_PRIORITY;
			}
		if (word_is(w, wn, "express"))
			q->express = 1, field = SET_EXPRESS;
		else if (word_is(w, wn, "best-effort"))
			q->best_effort = 1, field = SET_RELIABILITY;
		else if (word_is(w, wn, "reliable"))
			q->best_effort = 0, field = SET_RELIABILITY;
		else if (word_is(w, wn, "drop"))
			q->congestion = ZN_CONGESTION_DROP, field = SET_CONGESTION;
		else if (word_is(w, wn, "block"))
			q->congestion = ZN_CONGESTION_BLOCK, field = SET_CONGESTION;
		if (!field)
			FAIL("'%.*s' is not a priority (" PRIORITY_LIST ") or a flag (" FLAG_LIST ")", (int)wn, w);
		if (set & field)
			FAIL("'%.*s' names the %s a second time", (int)wn, w,
			     field == SET_PRIORITY	 ? "priority"
			     : field == SET_EXPRESS	 ? "express flag"
			     : field == SET_RELIABILITY ? "reliability (best-effort or reliable)"
							 : "congestion control (drop or block)");
		set |= field;
		if (!comma)
			break;
		s = comma + 1;
		n -= len + 1;
		if (n == 0)
			FAIL("an empty QoS item after '%.*s'", (int)wn, w);
	}
	return 0;
}

/* Orders the classes by priority (stable: table order, the default after the table's) and
 * renumbers the rules. */
static void sort_classes(zn_qos_table_t *t)
{
	uint8_t order[ZN_MAX_QOS_CLASSES], rank[ZN_MAX_QOS_CLASSES];
	size_t n = 0;
	for (uint8_t p = 1; p <= 7; p++)
		for (size_t c = 0; c < t->class_count; c++)
			if (t->classes[c].priority == p)
				order[n++] = (uint8_t)c;
	zn_qos_t sorted[ZN_MAX_QOS_CLASSES];
	for (size_t i = 0; i < n; i++) {
		sorted[i] = t->classes[order[i]];
		rank[order[i]] = (uint8_t)i;
	}
	memcpy(t->classes, sorted, n * sizeof(sorted[0]));
	for (size_t i = 0; i < t->rule_count; i++)
		t->rules[i].cls = rank[t->rules[i].cls];
	t->default_class = rank[t->default_class];
}

int zn_qos_parse(const char *text, const zn_qos_t *base, zn_qos_table_t *out, char *err, size_t err_len)
{
	memset(out, 0, sizeof(*out));
	if (base->priority < 1 || base->priority > 7)
		FAIL("default priority %u is not 1..7", base->priority);
	zn_qos_t rule_qos[ZN_MAX_QOS_RULES];
	const char *s = text ? text : "";
	size_t n = strlen(s);
	trim(&s, &n);
	while (n) {
		const char *semi = memchr(s, ';', n);
		size_t len = semi ? (size_t)(semi - s) : n;
		const char *rule = s;
		size_t rule_n = len;
		trim(&rule, &rule_n);
		const char *colon = memchr(rule, ':', rule_n);
		if (colon && colon == rule + 1 && rule[0] == 'e') /* e:ID is part of the range */
			colon = memchr(colon + 1, ':', rule_n - 2);
		if (rule_n == 0)
			FAIL("an empty rule (a ';' too many?)");
		if (!colon)
			FAIL("rule '%.*s' is not RANGE:QOS (e.g. 0x000-0x0FF:realtime,express)", (int)rule_n, rule);
		if (out->rule_count == ZN_MAX_QOS_RULES)
			FAIL("more than %d rules", ZN_MAX_QOS_RULES);
		zn_qos_rule_t *r = &out->rules[out->rule_count];
		size_t items_n = rule_n - (size_t)(colon + 1 - rule);
		const char *items = colon + 1;
		trim(&items, &items_n);
		if (parse_range(rule, (size_t)(colon - rule), r, err, err_len) != 0)
			return -1;
		if (items_n == 0)
			FAIL("rule '%.*s' names no QoS after ':'", (int)rule_n, rule);
		if (parse_items(items, items_n, base, &rule_qos[out->rule_count], err, err_len) != 0)
			return -1;
		for (size_t j = 0; j < out->rule_count; j++) {
			const zn_qos_rule_t *o = &out->rules[j];
			if (o->extended == r->extended && r->first <= o->last && o->first <= r->last)
				FAIL("%s0x%" PRIX32 "-0x%" PRIX32 " overlaps %s0x%" PRIX32 "-0x%" PRIX32
				     " (a frame must have one QoS)",
				     r->extended ? "e:" : "", r->first, r->last, o->extended ? "e:" : "", o->first, o->last);
		}
		out->rule_count++;
		if (!semi)
			break;
		s = semi + 1;
		n -= len + 1;
		if (n == 0)
			FAIL("an empty rule after the last ';'");
	}
	/* classes: the rules' distinct QoS in table order, then the default's */
	for (size_t i = 0; i <= out->rule_count; i++) {
		const zn_qos_t *q = i < out->rule_count ? &rule_qos[i] : base;
		size_t c = 0;
		while (c < out->class_count && !qos_equal(&out->classes[c], q))
			c++;
		if (c == out->class_count) {
			if (c == ZN_MAX_QOS_CLASSES)
				FAIL("more than %d distinct QoS classes (the default, rx_qos, included)", ZN_MAX_QOS_CLASSES);
			out->classes[out->class_count++] = *q;
		}
		if (i < out->rule_count)
			out->rules[i].cls = (uint8_t)c;
		else
			out->default_class = (uint8_t)c;
	}
	sort_classes(out);
	return 0;
}

void zn_qos_describe(const zn_qos_t *q, char *buf, size_t cap)
{
	snprintf(buf, cap, "%s,%s%s,%s", q->priority >= 1 && q->priority <= 7 ? priority_names[q->priority] : "?",
		 q->express ? "express," : "", q->congestion == ZN_CONGESTION_DROP ? "drop" : "block",
		 q->best_effort ? "best-effort" : "reliable");
}
