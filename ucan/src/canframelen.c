/* canframelen.c - see canframelen.h. The exact-stuffing path builds the real
 * bit stream (SOF..CRC) and counts stuff bits as a CAN controller inserts them. */
#include "canframelen.h"

#include <string.h>

#define CAN_CRC15_POLY 0x4599u
/* CRC delimiter, ACK slot, ACK delimiter, 7 EOF bits, 3 inter-frame bits: never stuffed. */
#define CAN_TRAILER_BITS 13u

struct bitstream {
	uint8_t bits[160]; /* longest stuffed region: EFF, 8 data bytes: 54 + 64 + CRC */
	unsigned len;
};

static void put_bits(struct bitstream *bs, uint32_t value, unsigned count)
{
	for (unsigned i = count; i-- > 0;)
		bs->bits[bs->len++] = (uint8_t)((value >> i) & 1u);
}

static uint16_t crc15(const struct bitstream *bs)
{
	uint16_t crc = 0;
	for (unsigned i = 0; i < bs->len; i++) {
		unsigned next = bs->bits[i] ^ ((crc >> 14) & 1u);
		crc = (uint16_t)((crc << 1) & 0x7fffu);
		if (next)
			crc ^= CAN_CRC15_POLY;
	}
	return crc;
}

static unsigned count_stuff_bits(const struct bitstream *bs)
{
	unsigned stuffed = 0, run = 1;
	uint8_t last = bs->bits[0];
	for (unsigned i = 1; i < bs->len; i++) {
		if (bs->bits[i] == last) {
			if (++run == 5) {
				/* the stuff bit is the complement and starts the next run */
				stuffed++;
				last = (uint8_t)!last;
				run = 1;
			}
		} else {
			last = bs->bits[i];
			run = 1;
		}
	}
	return stuffed;
}

static unsigned exact_bits(const struct canfd_frame *frame, unsigned data_bytes)
{
	struct bitstream bs = { .len = 0 };
	int eff = !!(frame->can_id & CAN_EFF_FLAG);
	int rtr = !!(frame->can_id & CAN_RTR_FLAG);
	unsigned dlc = frame->len > 8 ? 8 : frame->len;

	put_bits(&bs, 0, 1); /* SOF */
	if (eff) {
		uint32_t id = frame->can_id & CAN_EFF_MASK;
		put_bits(&bs, id >> 18, 11);
		put_bits(&bs, 1, 1); /* SRR */
		put_bits(&bs, 1, 1); /* IDE */
		put_bits(&bs, id & 0x3ffffu, 18);
		put_bits(&bs, (uint32_t)rtr, 1);
		put_bits(&bs, 0, 2); /* r1, r0 */
	} else {
		put_bits(&bs, frame->can_id & CAN_SFF_MASK, 11);
		put_bits(&bs, (uint32_t)rtr, 1);
		put_bits(&bs, 0, 2); /* IDE, r0 */
	}
	put_bits(&bs, dlc, 4);
	for (unsigned i = 0; i < data_bytes; i++)
		put_bits(&bs, frame->data[i], 8);
	put_bits(&bs, crc15(&bs), 15);
	return bs.len + count_stuff_bits(&bs) + CAN_TRAILER_BITS;
}

unsigned can_frame_bits(const struct canfd_frame *frame, int is_fd, enum ucan_stuffing stuffing)
{
	int eff = !!(frame->can_id & CAN_EFF_FLAG);
	unsigned data_bytes = (frame->can_id & CAN_RTR_FLAG) ? 0 : frame->len;
	unsigned max_len = is_fd ? CANFD_MAX_DLEN : CAN_MAX_DLEN;
	if (data_bytes > max_len)
		data_bytes = max_len;
	unsigned region = (eff ? 54u : 34u) + 8u * data_bytes; /* SOF..CRC */

	switch (stuffing) {
	case UCAN_STUFF_NONE:
		return region + CAN_TRAILER_BITS;
	case UCAN_STUFF_EXACT:
		if (!is_fd && data_bytes <= CAN_MAX_DLEN)
			return exact_bits(frame, data_bytes);
		/* FD payloads do not fit the classic bit layout: fall back to worst case */
		/* fall through */
	case UCAN_STUFF_WORST:
	default:
		return region + (region - 1) / 4 + CAN_TRAILER_BITS;
	}
}

uint32_t can_arbitration_key(canid_t can_id)
{
	uint32_t rtr = (can_id & CAN_RTR_FLAG) ? 1u : 0u;
	if (can_id & CAN_EFF_FLAG) {
		uint32_t id = can_id & CAN_EFF_MASK;
		return ((id >> 18) << 21) | (1u << 20) /* SRR */ | (1u << 19) /* IDE */ |
		       ((id & 0x3ffffu) << 1) | rtr;
	}
	return ((can_id & CAN_SFF_MASK) << 21) | (rtr << 20);
}
