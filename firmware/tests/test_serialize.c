/* test_serialize.c - the wire format against the golden vectors shared with
 * the Python bench (tests/data/wire_vectors.txt), plus round trips and
 * encoder refusals. */
#include <stdlib.h>
#include <string.h>

#include "check.h"
#include "zn_wire.h"

static size_t unhex(const char *hex, uint8_t *out, size_t cap)
{
	size_t n = 0;
	if (strcmp(hex, "-") == 0)
		return 0;
	for (; hex[0] && hex[1] && n < cap; hex += 2) {
		unsigned v;
		sscanf(hex, "%2x", &v);
		out[n++] = (uint8_t)v;
	}
	return n;
}

static void test_golden_vectors(void)
{
	FILE *f = fopen(WIRE_VECTORS, "r");
	CHECK(f != NULL);
	if (!f)
		return;
	char line[512];
	int lineno = 0, vectors = 0;
	while (fgets(line, sizeof(line), f)) {
		lineno++;
		if (line[0] == '#' || line[0] == '\n')
			continue;
		char name[64], hex[128], verdict[16], a[32], b[8], c[8], data_hex[32];
		unsigned dlc;
		int fields = sscanf(line, "%63s %127s %15s %31s %7s %7s %u %31s", name, hex, verdict, a, b, c, &dlc,
				    data_hex);
		uint8_t wire[64];
		size_t len = unhex(hex, wire, sizeof(wire));
		can_message_t msg;
		size_t count = 0;
		zn_wire_result_t rc = zn_wire_decode(wire, len, &msg, 1, &count); /* a frame is a batch of one */
		vectors++;
		if (strcmp(verdict, "ok") == 0) {
			CHECK(fields == 8);
			if (rc != ZN_WIRE_OK)
				fprintf(stderr, "%s:%d: %s: decode says %s\n", WIRE_VECTORS, lineno, name,
					zn_wire_reason(rc));
			CHECK(rc == ZN_WIRE_OK);
			CHECK(msg.identifier == strtoul(a, NULL, 16));
			CHECK(msg.extd == (b[0] == 'e'));
			CHECK(msg.rtr == (c[0] == 'r'));
			CHECK(msg.data_length_code == dlc);
			uint8_t data[8] = { 0 };
			size_t n = unhex(data_hex, data, sizeof(data));
			CHECK(msg.rtr ? n == 0 : n == dlc);
			CHECK(memcmp(msg.data, data, sizeof(data)) == 0);
			/* and the encoder produces exactly the golden bytes */
			uint8_t again[16];
			CHECK(zn_wire_encode(&msg, again, sizeof(again)) == 16);
			CHECK(memcmp(again, wire, 16) == 0);
			CHECK(count == 1);
		} else {
			CHECK(strcmp(verdict, "reject") == 0 && fields >= 4);
			if (strcmp(zn_wire_reason(rc), a) != 0)
				fprintf(stderr, "%s:%d: %s: expected %s, decode says %s\n", WIRE_VECTORS, lineno, name, a,
					zn_wire_reason(rc));
			CHECK(strcmp(zn_wire_reason(rc), a) == 0);
			CHECK(count == 0);
		}
	}
	fclose(f);
	CHECK(vectors >= 20);
}

static void test_encoder(void)
{
	can_message_t msg;
	uint8_t buf[16];
	memset(&msg, 0, sizeof(msg));
	msg.identifier = 0x123;
	msg.data_length_code = 2;
	memset(msg.data, 0xAA, sizeof(msg.data)); /* bytes beyond dlc must not leak onto the wire */
	CHECK(zn_wire_encode(&msg, buf, sizeof(buf)) == 16);
	CHECK(buf[8] == 0xAA && buf[9] == 0xAA && buf[10] == 0 && buf[15] == 0);
	CHECK(zn_wire_encode(&msg, buf, 15) == -1);
	CHECK(zn_wire_encode(NULL, buf, 16) == -1);
	CHECK(zn_wire_encode(&msg, NULL, 16) == -1);
	msg.data_length_code = 9;
	CHECK(zn_wire_encode(&msg, buf, 16) == -1);
	msg.data_length_code = 1;
	msg.identifier = 0x800;
	CHECK(zn_wire_encode(&msg, buf, 16) == -1);
	msg.extd = 1;
	CHECK(zn_wire_encode(&msg, buf, 16) == 16);
	msg.identifier = 0x20000000;
	CHECK(zn_wire_encode(&msg, buf, 16) == -1);
	/* remote frames: dlc kept, data never sent */
	msg.identifier = 0x100;
	msg.extd = 0;
	msg.rtr = 1;
	msg.data_length_code = 4;
	CHECK(zn_wire_encode(&msg, buf, 16) == 16);
	CHECK(buf[4] == 4 && buf[5] == ZN_WIRE_FLAG_RTR && buf[8] == 0);
}

static void test_batches(void)
{
	uint8_t buf[48];
	can_message_t in[3], out[3];
	size_t count = 99;
	memset(in, 0, sizeof(in));
	for (int i = 0; i < 3; i++) {
		in[i].identifier = (uint32_t)(0x100 + i);
		in[i].data_length_code = (uint8_t)i;
		in[i].data[0] = (uint8_t)(i ? i : 0);
		if (i == 0)
			in[i].data[0] = 0;
		CHECK(zn_wire_encode(&in[i], buf + 16 * i, 16) == 16);
	}
	CHECK(zn_wire_decode(buf, 48, out, 3, &count) == ZN_WIRE_OK && count == 3);
	CHECK(out[2].identifier == 0x102 && out[2].data_length_code == 2);
	CHECK(zn_wire_decode(buf, 48, out, 2, &count) == ZN_WIRE_ERR_LENGTH && count == 0);
	CHECK(zn_wire_decode(buf, 40, out, 3, &count) == ZN_WIRE_ERR_LENGTH);
	CHECK(zn_wire_decode(buf, 0, out, 3, &count) == ZN_WIRE_ERR_LENGTH);
	buf[16 + 4] = 9; /* one bad frame spoils the batch */
	CHECK(zn_wire_decode(buf, 48, NULL, 0, &count) == ZN_WIRE_ERR_DLC && count == 0);
}

/* the attachment: the worked example of zn_wire.h, and what a command's attachment must describe */
static void test_attachment(void)
{
	uint8_t att[ZN_ATTACHMENT_SIZE(2)], want[ZN_ATTACHMENT_SIZE(1)];
	zn_attachment_header(att, 1, 5);
	zn_attachment_set_time(att, 0, 1000);
	CHECK(unhex("010001000500000000000000e803000000000000", want, sizeof(want)) == sizeof(want));
	CHECK(memcmp(att, want, sizeof(want)) == 0);
	CHECK(zn_attachment_check(att, ZN_ATTACHMENT_SIZE(1), 1) == ZN_WIRE_OK);
	CHECK(zn_attachment_check(NULL, 0, 1) == ZN_WIRE_OK); /* optional */
	CHECK(zn_attachment_check(att, ZN_ATTACHMENT_SIZE(1), 2) == ZN_WIRE_ERR_ATTACHMENT); /* count */
	CHECK(zn_attachment_check(att, ZN_ATTACHMENT_SIZE(1) - 1, 1) == ZN_WIRE_ERR_ATTACHMENT); /* length */
	CHECK(zn_attachment_check(att, 5, 1) == ZN_WIRE_ERR_ATTACHMENT);
	att[0] = 2;
	CHECK(zn_attachment_check(att, ZN_ATTACHMENT_SIZE(1), 1) == ZN_WIRE_ERR_ATTACHMENT); /* version */
	CHECK(strcmp(zn_wire_reason(ZN_WIRE_ERR_ATTACHMENT), "attachment") == 0);
	CHECK(strcmp(zn_wire_reason((zn_wire_result_t)-10), "unknown") == 0);
}

/* can_msgs/msg/Frame in CDR: the bytes pycdr2 (the bench's decoder) writes for the same message */
static void test_ros2_frame(void)
{
	can_message_t m = { .identifier = 0x18DAF110, .extd = 1, .data_length_code = 3, .data = { 0xDE, 0xAD, 0xBE } };
	uint8_t buf[64], want[64];
	size_t want_len = unhex("0001000000f1536515cd5b07060000007663616e3000000010f1da1800010003deadbe0000000000", want,
				sizeof(want));
	int len = zn_ros2_encode_can_frame(&m, 1700000000123456789LL, "vcan0", buf, sizeof(buf));
	CHECK(len == (int)want_len && memcmp(buf, want, want_len) == 0);
	CHECK(zn_ros2_encode_can_frame(&m, 0, "vcan0", buf, want_len - 1) == -1); /* never past the buffer */
	m.rtr = 1; /* remote: no data bytes in the array */
	CHECK(zn_ros2_encode_can_frame(&m, 0, "vcan0", buf, sizeof(buf)) == (int)want_len && buf[want_len - 8] == 0);
}

int main(void)
{
	test_golden_vectors();
	test_encoder();
	test_batches();
	test_attachment();
	test_ros2_frame();
	CHECK_DONE("test_serialize");
}
