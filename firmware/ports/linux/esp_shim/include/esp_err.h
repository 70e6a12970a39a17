/* esp_err.h - Linux shim for the ESP-IDF error type, so zenoh-node compiles
 * unchanged on the host (as esp-protocols' Linux host tests do). */
#ifndef ESP_ERR_SHIM_H
#define ESP_ERR_SHIM_H

#include <stdint.h>

typedef int esp_err_t;
#define ESP_OK 0
#define ESP_FAIL -1
#define ESP_ERR_NO_MEM 0x101
#define ESP_ERR_INVALID_ARG 0x102
#define ESP_ERR_INVALID_STATE 0x103
#define ESP_ERR_INVALID_SIZE 0x104
#define ESP_ERR_NOT_FOUND 0x105
#define ESP_ERR_TIMEOUT 0x107

#endif
