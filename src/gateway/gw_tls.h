/* SPDX-License-Identifier: MIT */
/*
 * gw_tls.h - the gateway's TLS contexts, from its configuration: the
 * Modbus/TCP Security listener's ([tls]) and the robot links' ([robot] tls,
 * tls_ca, tls_fingerprint). The gateway starts the listener with the
 * first (gateway.c) and a reload renews both (config_reload.c).
 *
 * [tls] private_key is a file name, or, without any '/', the name of a
 * systemd credential (LoadCredential=): the file of that name in
 * $CREDENTIALS_DIRECTORY. The key file must be readable by its owner only.
 */
#ifndef JAKAGW_GW_TLS_H
#define JAKAGW_GW_TLS_H

#include <stddef.h>

#include "config.h"
#include "tls.h"

/*
 * Builds the server context of [tls] (its files loaded and checked) or the
 * client context of [robot] tls. Returns 0 with *out set, or a negative
 * errno with one line naming the key in 'why'.
 */
int gw_tls_server_context(const struct gw_config *cfg, struct tls_context **out, char *why,
                          size_t why_size);
int gw_tls_robot_context(const struct gw_config *cfg, struct tls_context **out, char *why,
                         size_t why_size);

/*
 * [robot] tls: the client context both robot links use (*ctx NULL when
 * tls is false), logged as 'what' ("robot links"): which CA or pinned
 * fingerprint verifies the controller, or why it cannot be loaded.
 * Returns 0 or -EINVAL.
 */
int gw_tls_robot_links(const struct gw_config *cfg, struct tls_context **ctx, const char *what);

/*
 * Loads every TLS file 'cfg' names, as the daemon would: for --check-config,
 * at start and on reload. Returns 0 or -EINVAL with the first error in
 * 'why' (one line naming the key).
 */
int gw_tls_check(const struct gw_config *cfg, char *why, size_t why_size);

#endif
