/* zn_port_can.h - contract of the CAN port: what zenoh-node needs from a CAN
 * controller. Linux: ports/linux/can_socketcan.c; ESP32 (planned): ports/esp32/can_twai.c;
 * tests: ports/mock/can_mock.c. */
#ifndef ZN_PORT_CAN_H
#define ZN_PORT_CAN_H

#include <stdint.h>

#include "driver/can.h"
#include "esp_err.h"

typedef struct zn_can zn_can_t;

/* Opens the named bus ("vcan0"; on the ESP32 the TWAI controller, name ignored). */
esp_err_t zn_can_open(const char *name, zn_can_t **out);

/* Waits up to timeout_ms for a frame. ESP_OK with *rx_time_ns (CLOCK_REALTIME
 * nanoseconds, taken by the driver/kernel when the frame arrived), ESP_ERR_TIMEOUT,
 * or ESP_FAIL when the bus is gone. Error frames are not returned. */
esp_err_t zn_can_receive(zn_can_t *can, can_message_t *msg, int64_t *rx_time_ns, int timeout_ms);

/* Transmits a validated frame; may wait up to timeout_ms for room in the tx queue. */
esp_err_t zn_can_transmit(zn_can_t *can, const can_message_t *msg, int timeout_ms);

/* Makes a blocked zn_can_receive return (shutdown), then frees the port. */
void zn_can_close(zn_can_t *can);

#endif
