/* driver/twai.h - Linux shim: the ESP-IDF TWAI message type (layout as in
 * ESP-IDF v5 hal/twai_types.h), without the driver. */
#ifndef TWAI_SHIM_H
#define TWAI_SHIM_H

#include <stdint.h>

#define TWAI_FRAME_MAX_DLC 8
#define TWAI_STD_ID_MASK 0x7FFu
#define TWAI_EXTD_ID_MASK 0x1FFFFFFFu

typedef struct {
	union {
		struct {
			uint32_t extd : 1;	   /* extended (29-bit) identifier */
			uint32_t rtr : 1;	   /* remote frame */
			uint32_t ss : 1;	   /* single shot */
			uint32_t self : 1;	   /* self reception request */
			uint32_t dlc_non_comp : 1; /* DLC > 8 allowed (not used by the bridge) */
			uint32_t reserved : 27;
		};
		uint32_t flags;
	};
	uint32_t identifier;
	uint8_t data_length_code;
	uint8_t data[TWAI_FRAME_MAX_DLC];
} twai_message_t;

#endif
