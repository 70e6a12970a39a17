/* zn_config_parse.h - zenoh-node configuration from environment and command
 * line (Linux). One table lists every option once: its flag, its environment
 * variable (the Kconfig name where there is one) and its help text. */
#ifndef ZN_CONFIG_PARSE_H
#define ZN_CONFIG_PARSE_H

#include <stddef.h>
#include <stdio.h>

#include "zn_node.h"

enum { ZN_CONFIG_OK = 0, ZN_CONFIG_ERROR = -1, ZN_CONFIG_HELP = 1 };

/* Defaults, then the environment, then argv. On error err holds one line. */
int zn_config_from_env_and_args(zn_node_config_t *cfg, int argc, char **argv, char *err, size_t err_len);

/* Parses "100-1FF,7E0,e:18DA0000-18DAFFFF" (hex; e: = 29-bit ids). */
int zn_parse_id_ranges(const char *text, zn_id_range_t *out, size_t max, size_t *count, char *err, size_t err_len);

void zn_config_usage(FILE *out);

#endif
