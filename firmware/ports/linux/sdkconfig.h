/* sdkconfig.h - Kconfig values for the Linux build (ESP-IDF generates this
 * file from Kconfig on the real target). Only the router address and the CAN
 * bus differ from the Kconfig defaults: on the bench the router is the local
 * one, never a vehicle network address, and the bus a SocketCAN interface. */
#ifndef ZN_LINUX_SDKCONFIG_H
#define ZN_LINUX_SDKCONFIG_H

#define CONFIG_ZENOH_NODE_ENABLED 1
#define CONFIG_ZENOH_ROUTER_ADDRESS "tcp/127.0.0.1:7447"
#define CONFIG_ZENOH_NODE_MODE 0
#define CONFIG_ZENOH_NODE_CAN "vcan0"
#define CONFIG_ZENOH_PUBLISH_PERIOD_MS 100
#define CONFIG_ZENOH_KEY_PREFIX "vehicle/can"
#define CONFIG_ZENOH_BATCH_MAX_FRAMES 256
#define CONFIG_ZENOH_RX_QUEUE_FRAMES 65536
#define CONFIG_ZENOH_TX_QUEUE_FRAMES 2048
#define CONFIG_ZENOH_TX_MAX_AGE_MS 0
#define CONFIG_ZENOH_TASK_STACK_BYTES 4096
#define CONFIG_ZENOH_COMPRESSION 0
#define CONFIG_ZENOH_LOW_LATENCY 0
#define CONFIG_ZENOH_ROS2_TOPIC ""
#define CONFIG_ZENOH_ROS2_DOMAIN 0
#define CONFIG_ZENOH_RX_QOS ""

#endif
