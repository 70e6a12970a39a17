/* config_args.h - the unit tests' way into the configuration parser: a NULL-terminated
 * list of flags parsed as zenoh-node's command line, after the environment. */
#ifndef ZN_CONFIG_ARGS_H
#define ZN_CONFIG_ARGS_H

#include <stdio.h>
#include <stdlib.h>

#include "zn_config_parse.h"

#define CONFIG_ARGS_MAX 32 /* argv entries, the program name and the closing NULL included */

/* err holds at least 256 bytes. A longer list than argv holds is the test's mistake: abort. */
static inline int parse_args(zn_node_config_t *cfg, char *err, const char *const *args)
{
	char *argv[CONFIG_ARGS_MAX];
	int argc = 0;
	argv[argc++] = "zenoh-node";
	for (; *args; args++) {
		if (argc == CONFIG_ARGS_MAX - 1) {
			fprintf(stderr, "parse_args: more than %d flags\n", CONFIG_ARGS_MAX - 2);
			abort();
		}
		argv[argc++] = (char *)*args;
	}
	argv[argc] = NULL;
	return zn_config_from_env_and_args(cfg, argc, argv, err, 256);
}

#endif
