/* test_core.c - unit tests of the hub's pure parts: frame length, arbitration
 * order, kernel filter semantics, message validation. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <linux/can/error.h>

#include "canfilter.h"
#include "canframelen.h"
#include "ucan_msg.h"

static int failures;
#define CHECK(cond)                                                                                                    \
	do {                                                                                                           \
		if (!(cond)) {                                                                                         \
			fprintf(stderr, "%s:%d: CHECK failed: %s\n", __FILE__, __LINE__, #cond);                      \
			failures++;                                                                                    \
		}                                                                                                      \
	} while (0)

static struct canfd_frame frame(canid_t id, unsigned len, uint8_t fill)
{
	struct canfd_frame f;
	memset(&f, 0, sizeof(f));
	f.can_id = id;
	f.len = (uint8_t)len;
	memset(f.data, fill, len);
	return f;
}

static void test_frame_bits(void)
{
	struct canfd_frame f = frame(0x123, 8, 0xaa);
	/* facts.md / can-utils canframelen.c table */
	CHECK(can_frame_bits(&f, 0, UCAN_STUFF_NONE) == 111);
	CHECK(can_frame_bits(&f, 0, UCAN_STUFF_WORST) == 135);
	f.can_id = 0x12345678 | CAN_EFF_FLAG;
	CHECK(can_frame_bits(&f, 0, UCAN_STUFF_NONE) == 131);
	CHECK(can_frame_bits(&f, 0, UCAN_STUFF_WORST) == 160);
	f = frame(0x123, 0, 0);
	CHECK(can_frame_bits(&f, 0, UCAN_STUFF_NONE) == 47);
	CHECK(can_frame_bits(&f, 0, UCAN_STUFF_WORST) == 55);
	/* remote frames carry no data whatever the DLC */
	f = frame(0x123 | CAN_RTR_FLAG, 8, 0);
	CHECK(can_frame_bits(&f, 0, UCAN_STUFF_NONE) == 47);
	/* id 0, no data: SOF..CRC is 34 zero bits; a stuff bit after every 5 equal bits: 6 */
	f = frame(0, 0, 0);
	CHECK(can_frame_bits(&f, 0, UCAN_STUFF_EXACT) == 34 + 6 + 13);
	/* exact always lies between unstuffed and worst case */
	for (unsigned id = 0; id < 0x800; id += 37)
		for (unsigned len = 0; len <= 8; len++) {
			f = frame(id, len, (uint8_t)(id * 7 + len));
			unsigned exact = can_frame_bits(&f, 0, UCAN_STUFF_EXACT);
			CHECK(exact >= can_frame_bits(&f, 0, UCAN_STUFF_NONE));
			CHECK(exact <= can_frame_bits(&f, 0, UCAN_STUFF_WORST));
		}
}

static void test_arbitration(void)
{
	CHECK(can_arbitration_key(0x100) < can_arbitration_key(0x101));
	/* same base id: standard data < standard remote < extended */
	CHECK(can_arbitration_key(0x100) < can_arbitration_key(0x100 | CAN_RTR_FLAG));
	CHECK(can_arbitration_key(0x100 | CAN_RTR_FLAG) < can_arbitration_key((0x100u << 18) | CAN_EFF_FLAG));
	/* an extended frame with a lower base id wins over a standard one */
	CHECK(can_arbitration_key((0x0ffu << 18) | 0x3ffff | CAN_EFF_FLAG) < can_arbitration_key(0x100));
	CHECK(can_arbitration_key(CAN_EFF_FLAG | 5) < can_arbitration_key(CAN_EFF_FLAG | 5 | CAN_RTR_FLAG));
}

static void test_filters(void)
{
	struct can_filter all = { 0, 0 };
	CHECK(can_raw_accepts(0x123, &all, 1, 0, 0));
	CHECK(can_raw_accepts(0x123 | CAN_EFF_FLAG, &all, 1, 0, 0));
	CHECK(can_raw_accepts(0x123 | CAN_RTR_FLAG, &all, 1, 0, 0));
	CHECK(!can_raw_accepts(CAN_ERR_FLAG | CAN_ERR_BUSOFF, &all, 1, 0, 0));
	CHECK(can_raw_accepts(CAN_ERR_FLAG | CAN_ERR_BUSOFF, &all, 1, CAN_ERR_BUSOFF, 0));
	CHECK(!can_raw_accepts(CAN_ERR_FLAG | CAN_ERR_CRTL, &all, 1, CAN_ERR_BUSOFF, 0));
	CHECK(!can_raw_accepts(0x123, NULL, 0, 0, 0)); /* empty filter list: nothing */

	struct can_filter exact = { 0x123, CAN_SFF_MASK };
	CHECK(can_raw_accepts(0x123, &exact, 1, 0, 0));
	CHECK(can_raw_accepts(0x123 | CAN_RTR_FLAG, &exact, 1, 0, 0)); /* RTR not in mask */
	CHECK(can_raw_accepts(0x123 | CAN_EFF_FLAG, &exact, 1, 0, 0)); /* EFF not in mask */
	struct can_filter sff_only = { 0x123, CAN_SFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG };
	CHECK(can_raw_accepts(0x123, &sff_only, 1, 0, 0));
	CHECK(!can_raw_accepts(0x123 | CAN_RTR_FLAG, &sff_only, 1, 0, 0));
	CHECK(!can_raw_accepts(0x123 | CAN_EFF_FLAG, &sff_only, 1, 0, 0));
	/* EFF flag in mask with a SFF id: upper id bits are ignored (kernel normalisation) */
	CHECK(!can_raw_accepts(0x12345123 | CAN_EFF_FLAG, &sff_only, 1, 0, 0));
	struct can_filter rtr_only = { 0x123 | CAN_RTR_FLAG, CAN_SFF_MASK | CAN_RTR_FLAG };
	CHECK(can_raw_accepts(0x123 | CAN_RTR_FLAG, &rtr_only, 1, 0, 0));
	CHECK(!can_raw_accepts(0x123, &rtr_only, 1, 0, 0));
	struct can_filter inverted = { 0x123 | CAN_INV_FILTER, CAN_SFF_MASK };
	CHECK(!can_raw_accepts(0x123, &inverted, 1, 0, 0));
	CHECK(can_raw_accepts(0x124, &inverted, 1, 0, 0));

	struct can_filter two[2] = { { 0x100, 0x700 }, { 0x010, 0x0f0 } };
	CHECK(can_raw_accepts(0x110, two, 2, 0, 0));
	CHECK(can_raw_accepts(0x120, two, 2, 0, 0));
	CHECK(can_raw_accepts(0x110, two, 2, 0, 1));  /* joined: both match */
	CHECK(!can_raw_accepts(0x120, two, 2, 0, 1)); /* joined: only one matches */
}

static void test_validate(void)
{
	struct ucan_ifinfo ifs[2] = { { "vcan0", UCAN_IFINDEX_BASE, CANFD_MTU, 0, 0 },
				      { "vcan1", UCAN_IFINDEX_BASE + 1, CAN_MTU, 0, 0 } };
	uint8_t buf[256];
	struct ucan_txhdr tx = { UCAN_MSG_FRAME, UCAN_IFINDEX_BASE };
	struct canfd_frame f = frame(0x123, 8, 1);

	memcpy(buf, &tx, sizeof(tx));
	memcpy(buf + sizeof(tx), &f, CAN_MTU);
	CHECK(ucan_msg_validate(buf, sizeof(tx) + CAN_MTU, ifs, 2) == UCAN_MSG_FRAME);
	CHECK(ucan_msg_validate(buf, sizeof(tx) + CAN_MTU - 1, ifs, 2) == UCAN_MSG_ERR_LENGTH);
	CHECK(ucan_msg_validate(buf, 2, ifs, 2) == UCAN_MSG_ERR_SHORT);
	f.len = 9;
	memcpy(buf + sizeof(tx), &f, CAN_MTU);
	CHECK(ucan_msg_validate(buf, sizeof(tx) + CAN_MTU, ifs, 2) == UCAN_MSG_ERR_FRAME);
	f = frame(0x123, 64, 1);
	memcpy(buf + sizeof(tx), &f, CANFD_MTU);
	CHECK(ucan_msg_validate(buf, sizeof(tx) + CANFD_MTU, ifs, 2) == UCAN_MSG_FRAME);
	tx.ifindex = UCAN_IFINDEX_BASE + 1; /* mtu 16: no FD */
	memcpy(buf, &tx, sizeof(tx));
	CHECK(ucan_msg_validate(buf, sizeof(tx) + CANFD_MTU, ifs, 2) == UCAN_MSG_ERR_FRAME);
	tx.ifindex = 7;
	memcpy(buf, &tx, sizeof(tx));
	CHECK(ucan_msg_validate(buf, sizeof(tx) + CAN_MTU, ifs, 2) == UCAN_MSG_ERR_IFINDEX);

	struct ucan_sockopts opts = { .type = UCAN_MSG_BIND, .ifindex = 0, .loopback = 1, .nfilters = 1 };
	memcpy(buf, &opts, sizeof(opts));
	memset(buf + sizeof(opts), 0, sizeof(struct can_filter));
	CHECK(ucan_msg_validate(buf, sizeof(opts) + sizeof(struct can_filter), ifs, 2) == UCAN_MSG_BIND);
	CHECK(ucan_msg_validate(buf, sizeof(opts), ifs, 2) == UCAN_MSG_ERR_LENGTH);
	opts.nfilters = 100000;
	memcpy(buf, &opts, sizeof(opts));
	CHECK(ucan_msg_validate(buf, sizeof(opts), ifs, 2) == UCAN_MSG_ERR_FILTERS);
	opts.nfilters = 0;
	opts.recv_own = 2;
	memcpy(buf, &opts, sizeof(opts));
	CHECK(ucan_msg_validate(buf, sizeof(opts), ifs, 2) == UCAN_MSG_ERR_FLAGS);

	uint32_t type = 999;
	memcpy(buf, &type, sizeof(type));
	CHECK(ucan_msg_validate(buf, sizeof(type), ifs, 2) == UCAN_MSG_ERR_TYPE);
	struct ucan_barrier barrier = { UCAN_MSG_BARRIER, { 0 } };
	memset(barrier.cookie, 'x', sizeof(barrier.cookie));
	CHECK(ucan_msg_validate((const uint8_t *)&barrier, sizeof(barrier), ifs, 2) == UCAN_MSG_ERR_COOKIE);
}

/* Appends one record (ucan_txrec + size bytes of f) at *at. */
static void put_record(uint8_t *buf, size_t *at, uint32_t ifindex, uint32_t size, const struct canfd_frame *f)
{
	struct ucan_txrec rec = { ifindex, size };
	memcpy(buf + *at, &rec, sizeof(rec));
	memcpy(buf + *at + sizeof(rec), f, size);
	*at += sizeof(rec) + size;
}

/* A batch is refused whole if any record is wrong, and must be filled exactly. */
static void test_validate_batch(void)
{
	struct ucan_ifinfo ifs[2] = { { "vcan0", UCAN_IFINDEX_BASE, CANFD_MTU, 0, 0 },
				      { "vcan1", UCAN_IFINDEX_BASE + 1, CAN_MTU, 0, 0 } };
	uint8_t buf[512];
	struct canfd_frame classic = frame(0x123, 8, 1), fd = frame(0x456, 64, 2), long_classic = frame(0x1, 9, 3);
	struct ucan_txbatch head = { UCAN_MSG_FRAMES, 3 };
	size_t at = sizeof(head);
	memcpy(buf, &head, sizeof(head));
	put_record(buf, &at, UCAN_IFINDEX_BASE, CAN_MTU, &classic);
	put_record(buf, &at, UCAN_IFINDEX_BASE, CANFD_MTU, &fd);
	put_record(buf, &at, UCAN_IFINDEX_BASE + 1, CAN_MTU, &classic);
	CHECK(ucan_msg_validate(buf, at, ifs, 2) == UCAN_MSG_FRAMES);
	CHECK(ucan_msg_validate(buf, at - 1, ifs, 2) == UCAN_MSG_ERR_LENGTH); /* last record cut */
	CHECK(ucan_msg_validate(buf, at + 4, ifs, 2) == UCAN_MSG_ERR_LENGTH); /* bytes beyond count */
	CHECK(ucan_msg_validate(buf, 6, ifs, 2) == UCAN_MSG_ERR_SHORT);
	head.count = 4; /* a record more than the message holds */
	memcpy(buf, &head, sizeof(head));
	CHECK(ucan_msg_validate(buf, at, ifs, 2) == UCAN_MSG_ERR_LENGTH);
	head.count = 0;
	memcpy(buf, &head, sizeof(head));
	CHECK(ucan_msg_validate(buf, sizeof(head), ifs, 2) == UCAN_MSG_ERR_LENGTH);
	head.count = UINT32_MAX; /* a count the length cannot hold ends at the length */
	memcpy(buf, &head, sizeof(head));
	CHECK(ucan_msg_validate(buf, at, ifs, 2) == UCAN_MSG_ERR_LENGTH);

	struct { uint32_t ifindex, size; struct canfd_frame *f; int err; } bad[] = {
		{ UCAN_IFINDEX_BASE + 1, CANFD_MTU, &fd, UCAN_MSG_ERR_FRAME }, /* FD on a classic interface */
		{ UCAN_IFINDEX_BASE, CAN_MTU, &long_classic, UCAN_MSG_ERR_FRAME },
		{ 7, CAN_MTU, &classic, UCAN_MSG_ERR_IFINDEX },
		{ UCAN_IFINDEX_BASE, 20, &classic, UCAN_MSG_ERR_LENGTH },
		{ UCAN_IFINDEX_BASE, UINT32_MAX, &classic, UCAN_MSG_ERR_LENGTH }, /* a size past the message */
	};
	struct ucan_ifinfo paced[2] = { ifs[0], { "vcan1", UCAN_IFINDEX_BASE + 1, CAN_MTU, 500000, 0 } };
	head.count = 2;
	memcpy(buf, &head, sizeof(head));
	at = sizeof(head);
	put_record(buf, &at, UCAN_IFINDEX_BASE, CAN_MTU, &classic);
	put_record(buf, &at, UCAN_IFINDEX_BASE + 1, CAN_MTU, &classic);
	CHECK(ucan_msg_validate(buf, at, paced, 2) == UCAN_MSG_ERR_PACED); /* one per message on a wire */
	for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
		head.count = 2;
		memcpy(buf, &head, sizeof(head));
		at = sizeof(head);
		put_record(buf, &at, UCAN_IFINDEX_BASE, CAN_MTU, &classic);
		size_t rec_at = at;
		uint32_t size = bad[i].size > CANFD_MTU ? CAN_MTU : bad[i].size;
		put_record(buf, &at, bad[i].ifindex, size, bad[i].f);
		memcpy(buf + rec_at + sizeof(uint32_t), &bad[i].size, sizeof(uint32_t));
		CHECK(ucan_msg_validate(buf, at, ifs, 2) == bad[i].err);
	}
}

int main(void)
{
	test_frame_bits();
	test_arbitration();
	test_filters();
	test_validate();
	test_validate_batch();
	if (failures) {
		fprintf(stderr, "%d check(s) failed\n", failures);
		return 1;
	}
	printf("test_core: all checks passed\n");
	return 0;
}
