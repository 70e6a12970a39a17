/* driver/can.h - Linux shim: ESP-IDF's legacy CAN names for the TWAI types. */
#ifndef CAN_SHIM_H
#define CAN_SHIM_H

#include "driver/twai.h"

typedef twai_message_t can_message_t;
#define CAN_EXTD_ID_MASK TWAI_EXTD_ID_MASK
#define CAN_STD_ID_MASK TWAI_STD_ID_MASK

#endif
