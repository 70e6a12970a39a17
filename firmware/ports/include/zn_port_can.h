/* zn_port_can.h - contract of the CAN port: what zenoh-node needs from a CAN
 * controller. Linux: ports/linux/can_socketcan.c; ESP32 (planned): ports/esp32/can_twai.c;
 * tests: ports/mock/can_mock.c. */
#ifndef ZN_PORT_CAN_H
#define ZN_PORT_CAN_H

#include <stddef.h>
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

/* Bursts: what a driver holds is moved with one call where it has one (Linux:
 * recvmmsg / sendmmsg), so a busy bus costs a syscall per burst, not per frame. */
#define ZN_CAN_BURST_MAX 64 /* frames one burst call moves at most */

typedef struct {
	can_message_t msg;
	int64_t rx_time_ns; /* as zn_can_receive's: the driver's/kernel's stamp of this frame */
} zn_can_rx_t;

/* Waits up to timeout_ms (0: not at all) for a frame, then returns the frames
 * already received, up to max (<= ZN_CAN_BURST_MAX), oldest first, each with
 * its own stamp. ESP_OK with *count >= 1, ESP_ERR_TIMEOUT (*count 0), ESP_FAIL
 * when the bus is gone (frames read before that are returned first). Error
 * frames are not returned. One reader per port. */
esp_err_t zn_can_receive_burst(zn_can_t *can, zn_can_rx_t *out, size_t max, size_t *count, int timeout_ms);

/* How many received frames the port holds before it drops one, a lower bound
 * (Linux: the socket's receive buffer over a frame's worst-case kernel size):
 * a reader that drains only now and then must come back before this many arrive. */
size_t zn_can_rx_capacity(zn_can_t *can);

/* Transmits validated frames in order, waiting up to timeout_ms for room for
 * each (as zn_can_transmit). *sent: how many went (msgs[0..*sent)). ESP_OK when
 * all did; else as zn_can_transmit for msgs[*sent] (ESP_ERR_TIMEOUT, ESP_FAIL). */
esp_err_t zn_can_send_burst(zn_can_t *can, const can_message_t *msgs, size_t n, size_t *sent, int timeout_ms);

/* Makes a blocked zn_can_receive return (shutdown), then frees the port. */
void zn_can_close(zn_can_t *can);

#endif
