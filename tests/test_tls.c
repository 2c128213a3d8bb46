/* SPDX-License-Identifier: MIT */
/*
 * test_tls.c - the TLS engine: contexts, handshakes between a server and a
 * client connection in memory, roles, refusals and their reasons, the
 * fingerprint pin, renegotiation, key file permissions; and the mbaps
 * transport on a real loop and real sockets, for how it schedules
 * handshakes. The certificates come from tests/tls/make-pki.sh (the
 * commands of docs/security.md).
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include <openssl/ssl.h>

/* The .c itself: the tests reach a connection's SSL (resumption, renegotiation). */
#include "tls.c"

#include "mb_server.h"
#include "mb_tls.h"
#include "regmap.h"

static char pki[256];

static const char *file(const char *name)
{
    static char paths[8][320];
    static int next;
    char *p = paths[next++ % 8];
    snprintf(p, 320, "%s/%s", pki, name);
    return p;
}

static int make_pki(void **state)
{
    char cmd[640];
    (void)state;
    snprintf(pki, sizeof(pki), "/tmp/jakagw-test-tls-XXXXXX");
    if (!mkdtemp(pki))
        return -1;
    snprintf(cmd, sizeof(cmd), "%s/../tls/make-pki.sh %s/pki >/dev/null", SAMPLES_DIR, pki);
    if (system(cmd) != 0)
        return -1;
    strcat(pki, "/pki");
    return 0;
}

static int remove_pki(void **state)
{
    char cmd[400];
    (void)state;
    pki[strlen(pki) - 4] = '\0';
    snprintf(cmd, sizeof(cmd), "rm -rf %s", pki);
    return system(cmd) == 0 ? 0 : -1;
}

static struct tls_settings server_settings(void)
{
    struct tls_settings s = {
        .server = true,
        .certificate = file("gateway.crt"),
        .private_key = file("gateway.key"),
        .ca = file("ca.crt"),
        .crl = file("ca.crl"),
        .min_version = 12,
        .certificate_key = "[tls] certificate",
        .private_key_key = "[tls] private_key",
        .ca_key = "[tls] client_ca",
        .crl_key = "[tls] crl",
        .fingerprint_key = "",
    };
    return s;
}

static struct tls_context *server_ctx(void)
{
    struct tls_settings s = server_settings();
    struct tls_context *ctx;
    char why[400];
    int rc = tls_context_new(&s, &ctx, why, sizeof(why));
    if (rc)
        fail_msg("server context: %s", why);
    return ctx;
}

/* A client context as a PLC has it: its certificate, the gateway's CA. */
static struct tls_context *client_ctx(const char *name, int max_version)
{
    char crt[64], key[64], why[400];
    struct tls_context *ctx;

    snprintf(crt, sizeof(crt), "%s.crt", name);
    snprintf(key, sizeof(key), "%s.key", name);
    struct tls_settings s = {
        .certificate = name ? file(crt) : NULL,
        .private_key = name ? file(key) : NULL,
        .ca = file("ca.crt"),
        .min_version = 12,
        .certificate_key = "cert",
        .private_key_key = "key",
        .ca_key = "ca",
        .crl_key = "crl",
        .fingerprint_key = "fingerprint",
    };
    assert_int_equal(tls_context_new(&s, &ctx, why, sizeof(why)), 0);
    (void)max_version;
    return ctx;
}

/* Moves every pending byte from 'from' to 'to'; returns how many. */
static size_t pump(struct tls_conn *from, struct tls_conn *to)
{
    uint8_t buf[4096];
    size_t total = 0, n;
    while ((n = tls_conn_take(from, buf, sizeof(buf))) > 0) {
        assert_int_equal(tls_conn_feed(to, buf, n), 0);
        total += n;
    }
    return total;
}

/* Runs both handshakes to their end; returns the server's result. */
static int handshake(struct tls_conn *server, struct tls_conn *client, int *client_rc)
{
    int s = TLS_AGAIN, c = TLS_AGAIN;
    for (int round = 0; round < 20; round++) {
        if (c == TLS_AGAIN)
            c = tls_conn_handshake(client);
        pump(client, server);
        if (s == TLS_AGAIN)
            s = tls_conn_handshake(server);
        size_t moved = pump(server, client);
        if (s != TLS_AGAIN && (c != TLS_AGAIN || moved == 0))
            break;
    }
    if (client_rc)
        *client_rc = c;
    return s;
}

static void role_is_read_from_the_certificate(void **state)
{
    struct tls_context *sctx = server_ctx(), *cctx = client_ctx("operator", 0);
    struct tls_conn *s = tls_conn_new(sctx, NULL), *c = tls_conn_new(cctx, "127.0.0.1");
    bool valid;
    char buf[64];
    int crc;
    (void)state;

    assert_int_equal(handshake(s, c, &crc), TLS_OK);
    assert_int_equal(crc, TLS_OK);
    assert_string_equal(tls_conn_role(s, &valid), "operator");
    assert_true(valid);
    assert_non_null(strstr(tls_conn_subject(s), "CN=plc-operator"));
    assert_string_equal(tls_conn_version(s), "TLSv1.3");

    /* Plaintext both ways, through the memory BIOs. */
    assert_int_equal(tls_conn_write(c, "\x00\x01\x00\x00\x00\x06\x01\x04\x00\x00\x00\x01", 12), 0);
    pump(c, s);
    assert_int_equal(tls_conn_read(s, buf, sizeof(buf)), 12);
    assert_int_equal(tls_conn_read(s, buf, sizeof(buf)), TLS_AGAIN);
    assert_int_equal(tls_conn_write(s, "reply", 5), 0);
    pump(s, c);
    assert_int_equal(tls_conn_read(c, buf, sizeof(buf)), 5);
    assert_memory_equal(buf, "reply", 5);

    /* close_notify reads as the end. */
    tls_conn_close_notify(c);
    pump(c, s);
    assert_int_equal(tls_conn_read(s, buf, sizeof(buf)), TLS_CLOSED);
    tls_conn_free(s);
    tls_conn_free(c);
    tls_context_unref(cctx);
    tls_context_unref(sctx);
}

/*
 * A role is taken as UTF-8 in any language; one that is not taken says
 * why: too long (a 5000-byte UTF8String is valid, just too long), not a
 * UTF8String at all.
 */
static void roles_taken_or_refused_for_the_real_reason(void **state)
{
    static const struct {
        const char *cert, *role, *problem;
        bool valid;
    } cases[] = {
        {"utf8role", "op\xC3\xA9rateur", "", true},
        {"longrole", "", "too long (5000 bytes; at most 63)", false},
        {"ia5role", "", "not a valid UTF8String", false},
    };
    (void)state;

    for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
        struct tls_context *sctx = server_ctx(), *cctx = client_ctx(cases[i].cert, 0);
        struct tls_conn *s = tls_conn_new(sctx, NULL), *c = tls_conn_new(cctx, NULL);
        bool valid;

        assert_int_equal(handshake(s, c, NULL), TLS_OK);
        assert_string_equal(tls_conn_role(s, &valid), cases[i].role);
        assert_int_equal(valid, cases[i].valid);
        assert_string_equal(tls_conn_role_problem(s), cases[i].problem);
        tls_conn_free(s);
        tls_conn_free(c);
        tls_context_unref(cctx);
        tls_context_unref(sctx);
    }
    assert_null(tls_role_name_problem("\xE6\x93\x8D\xE4\xBD\x9C", 6));
    assert_string_equal(tls_role_name_problem("op\xC3", 3), "not valid UTF-8");
    assert_string_equal(tls_role_name_problem("\xC0\xAF", 2), "not valid UTF-8"); /* overlong */
    assert_string_equal(tls_role_name_problem("a b", 3), "has a space or a control character");
    assert_string_equal(tls_role_name_problem("a\xC2\x85", 3), "has a space or a control character");
}

static void no_role_reads_empty(void **state)
{
    struct tls_context *sctx = server_ctx(), *cctx = client_ctx("norole", 0);
    struct tls_conn *s = tls_conn_new(sctx, NULL), *c = tls_conn_new(cctx, NULL);
    bool valid;
    (void)state;

    assert_int_equal(handshake(s, c, NULL), TLS_OK);
    assert_string_equal(tls_conn_role(s, &valid), "");
    assert_true(valid);
    tls_conn_free(s);
    tls_conn_free(c);
    tls_context_unref(cctx);
    tls_context_unref(sctx);
}

static void expect_refusal(const char *name, enum tls_failure expected)
{
    struct tls_context *sctx = server_ctx(), *cctx = client_ctx(name, 0);
    struct tls_conn *s = tls_conn_new(sctx, NULL), *c = tls_conn_new(cctx, NULL);
    char why[200];

    assert_int_equal(handshake(s, c, NULL), TLS_ERROR);
    if (tls_conn_failure(s, why, sizeof(why)) != expected)
        fail_msg("%s: failure %s (%s), expected %s", name ? name : "no certificate",
                 tls_failure_name(tls_conn_failure(s, NULL, 0)), why,
                 tls_failure_name(expected));
    tls_conn_free(s);
    tls_conn_free(c);
    tls_context_unref(cctx);
    tls_context_unref(sctx);
}

static void refusals_say_why(void **state)
{
    (void)state;
    expect_refusal(NULL, TLS_FAIL_NO_CERTIFICATE);
    expect_refusal("stranger", TLS_FAIL_UNTRUSTED);
    expect_refusal("expired", TLS_FAIL_EXPIRED);
    expect_refusal("revoked", TLS_FAIL_REVOKED);
}

static void plaintext_is_a_protocol_failure(void **state)
{
    struct tls_context *sctx = server_ctx();
    struct tls_conn *s = tls_conn_new(sctx, NULL);
    const char modbus[] = "\x00\x01\x00\x00\x00\x06\x01\x04\x00\x00\x00\x01";
    (void)state;

    assert_int_equal(tls_conn_feed(s, modbus, 12), 0);
    assert_int_equal(tls_conn_handshake(s), TLS_ERROR);
    assert_int_equal(tls_conn_failure(s, NULL, 0), TLS_FAIL_PROTOCOL);
    tls_conn_free(s);
    tls_context_unref(sctx);
}

static void session_is_resumed(void **state)
{
    struct tls_context *sctx = server_ctx(), *cctx = client_ctx("operator", 0);
    struct tls_conn *s = tls_conn_new(sctx, NULL), *c = tls_conn_new(cctx, NULL);
    SSL_SESSION *session;
    char buf[16];
    (void)state;

    assert_int_equal(handshake(s, c, NULL), TLS_OK);
    /* TLS 1.3 tickets come after the handshake: read them. */
    assert_int_equal(tls_conn_write(s, "x", 1), 0);
    pump(s, c);
    assert_int_equal(tls_conn_read(c, buf, sizeof(buf)), 1);
    session = SSL_get1_session(c->ssl);
    assert_non_null(session);
    assert_true(SSL_SESSION_is_resumable(session));
    /* Freed without close_notify, OpenSSL would take the session back. */
    tls_conn_close_notify(c);
    tls_conn_close_notify(s);
    tls_conn_free(s);
    tls_conn_free(c);

    s = tls_conn_new(sctx, NULL);
    c = tls_conn_new(cctx, NULL);
    SSL_set_session(c->ssl, session);
    assert_int_equal(handshake(s, c, NULL), TLS_OK);
    assert_true(tls_conn_resumed(s));
    assert_string_equal(tls_conn_role(s, NULL), "operator");
    SSL_SESSION_free(session);
    tls_conn_free(s);
    tls_conn_free(c);
    tls_context_unref(cctx);
    tls_context_unref(sctx);
}

static void renegotiation_fails_the_connection(void **state)
{
    struct tls_settings ss = server_settings();
    struct tls_context *sctx, *cctx = client_ctx("operator", 0);
    struct tls_conn *s, *c;
    char why[200], buf[16];
    (void)state;

    ss.min_version = 12;
    assert_int_equal(tls_context_new(&ss, &sctx, why, sizeof(why)), 0);
    s = tls_conn_new(sctx, NULL);
    c = tls_conn_new(cctx, NULL);
    SSL_set_max_proto_version(c->ssl, TLS1_2_VERSION);
    assert_int_equal(handshake(s, c, NULL), TLS_OK);
    assert_string_equal(tls_conn_version(s), "TLSv1.2");
    SSL_clear_options(c->ssl, SSL_OP_NO_RENEGOTIATION); /* a client that tries */
    assert_int_equal(SSL_renegotiate(c->ssl), 1);
    SSL_do_handshake(c->ssl);
    pump(c, s);
    assert_int_equal(tls_conn_read(s, buf, sizeof(buf)), TLS_ERROR);
    assert_int_equal(tls_conn_failure(s, why, sizeof(why)), TLS_FAIL_PROTOCOL);
    assert_string_equal(why, "renegotiation refused");
    tls_conn_free(s);
    tls_conn_free(c);
    tls_context_unref(cctx);
    tls_context_unref(sctx);
}

static void fingerprint_pin(void **state)
{
    struct tls_context *sctx = server_ctx(), *cctx;
    struct tls_conn *s, *c;
    char cmd[600], fp[128] = "", why[300];
    FILE *p;
    (void)state;

    snprintf(cmd, sizeof(cmd),
             "openssl x509 -in %s -noout -fingerprint -sha256 | cut -d= -f2", file("gateway.crt"));
    p = popen(cmd, "r");
    assert_non_null(p);
    assert_non_null(fgets(fp, sizeof(fp), p));
    pclose(p);
    fp[strcspn(fp, "\n")] = '\0';

    struct tls_settings cs = {
        .certificate = file("operator.crt"), .private_key = file("operator.key"),
        .fingerprint = fp, .min_version = 12, .certificate_key = "c",
        .private_key_key = "k", .ca_key = "[robot] tls_ca", .crl_key = "crl",
        .fingerprint_key = "[robot] tls_fingerprint",
    };
    assert_int_equal(tls_context_new(&cs, &cctx, why, sizeof(why)), 0);
    s = tls_conn_new(sctx, NULL);
    c = tls_conn_new(cctx, "127.0.0.1");
    int crc;
    assert_int_equal(handshake(s, c, &crc), TLS_OK);
    assert_int_equal(crc, TLS_OK);
    tls_conn_free(s);
    tls_conn_free(c);
    tls_context_unref(cctx);

    fp[1] = fp[1] == '0' ? '1' : '0';
    assert_int_equal(tls_context_new(&cs, &cctx, why, sizeof(why)), 0);
    s = tls_conn_new(sctx, NULL);
    c = tls_conn_new(cctx, "127.0.0.1");
    handshake(s, c, &crc);
    assert_int_equal(crc, TLS_ERROR);
    assert_int_equal(tls_conn_failure(c, why, sizeof(why)), TLS_FAIL_FINGERPRINT);
    tls_conn_free(s);
    tls_conn_free(c);
    tls_context_unref(cctx);

    cs.fingerprint = "12:34";
    assert_int_equal(tls_context_new(&cs, &cctx, why, sizeof(why)), -EINVAL);
    assert_non_null(strstr(why, "[robot] tls_fingerprint: "));
    tls_context_unref(sctx);
}

static void client_checks_the_server_name(void **state)
{
    struct tls_context *sctx = server_ctx(), *cctx = client_ctx("operator", 0);
    struct tls_conn *s = tls_conn_new(sctx, NULL), *c = tls_conn_new(cctx, "10.9.9.9");
    char why[200];
    int crc;
    (void)state;

    handshake(s, c, &crc);
    assert_int_equal(crc, TLS_ERROR);
    assert_int_equal(tls_conn_failure(c, why, sizeof(why)), TLS_FAIL_UNTRUSTED);
    tls_conn_free(s);
    tls_conn_free(c);
    tls_context_unref(cctx);
    tls_context_unref(sctx);
}

static void bad_files_name_their_key(void **state)
{
    struct tls_settings s = server_settings();
    struct tls_context *ctx;
    char why[400];
    (void)state;

    assert_int_equal(chmod(file("gateway.key"), 0644), 0);
    assert_int_equal(tls_context_new(&s, &ctx, why, sizeof(why)), -EPERM);
    assert_non_null(strstr(why, "[tls] private_key: "));
    assert_non_null(strstr(why, "accessible by other users (mode 0644)"));
    assert_int_equal(chmod(file("gateway.key"), 0600), 0);

    s.private_key = file("operator.key");
    assert_int_equal(tls_context_new(&s, &ctx, why, sizeof(why)), -EINVAL);
    assert_non_null(strstr(why, "does not match the certificate of [tls] certificate"));

    s = server_settings();
    s.certificate = file("no-such.crt");
    assert_int_equal(tls_context_new(&s, &ctx, why, sizeof(why)), -ENOENT);
    assert_non_null(strstr(why, "[tls] certificate: "));

    s = server_settings();
    s.ca = file("ca.cnf");
    assert_int_equal(tls_context_new(&s, &ctx, why, sizeof(why)), -EINVAL);
    assert_non_null(strstr(why, "[tls] client_ca: "));

    s = server_settings();
    s.crl = file("ca.crt");
    assert_int_equal(tls_context_new(&s, &ctx, why, sizeof(why)), -EINVAL);
    assert_non_null(strstr(why, "[tls] crl: "));

    s = server_settings();
    s.private_key = "";
    assert_int_equal(tls_context_new(&s, &ctx, why, sizeof(why)), -EINVAL);
    assert_null(ctx);
}

/* A context freed while a connection holds it lives until that closes. */
static void context_outlives_its_owner(void **state)
{
    struct tls_context *sctx = server_ctx(), *cctx = client_ctx("monitor", 0);
    struct tls_conn *s = tls_conn_new(sctx, NULL), *c = tls_conn_new(cctx, NULL);
    (void)state;

    tls_context_unref(sctx);
    tls_context_unref(cctx);
    assert_int_equal(handshake(s, c, NULL), TLS_OK);
    assert_string_equal(tls_conn_role(s, NULL), "monitor");
    tls_conn_free(s);
    tls_conn_free(c);
}

/* ---- the mbaps transport on a loop ---- */

static uint32_t rights_read_only(void *user, const char *role, bool valid, bool *listed)
{
    (void)user, (void)role, (void)valid;
    *listed = false;
    return 0;
}

static bool server_closed;
static void on_server_closed(struct mb_server *srv)
{
    (void)srv;
    server_closed = true;
}

#define SHAKERS 4

/*
 * Handshake work goes one step per turn of the loop: four ClientHellos that
 * all arrive in one turn are answered over four turns, not in one (which,
 * with many at once, would keep the loop from the PLCs already served).
 */
static void handshakes_take_one_step_per_loop_turn(void **state)
{
    uv_loop_t loop;
    struct regmap map;
    struct regmap_image img;
    static struct mb_server srv;
    static struct mb_tls t;
    struct mb_server_config cfg = {.bind = "127.0.0.1", .port = 0, .max_clients = 8,
                                   .frame_timeout_ms = 1000, .unit_id = -1};
    struct mb_server_hooks hooks = {0};
    struct mb_tls_config tc = {.handshake_timeout_ms = 10000, .max_handshakes = 16,
                               .rights_for_role = rights_read_only};
    struct tls_context *cctx = client_ctx("operator", 0);
    struct tls_conn *client[SHAKERS];
    int fd[SHAKERS];
    bool answered[SHAKERS] = {false};
    (void)state;

    memset(&srv, 0, sizeof(srv));
    assert_int_equal(uv_loop_init(&loop), 0);
    assert_int_equal(regmap_init(&map), 0);
    assert_int_equal(regmap_image_init(&img, &map, REGMAP_HIGH_WORD_FIRST), 0);
    assert_int_equal(mb_server_start(&loop, &srv, &cfg, &img, &hooks), 0);
    assert_int_equal(mb_tls_init(&t, server_ctx(), &tc), 0);
    assert_int_equal(mb_server_listen(&srv, "127.0.0.1", 0, 0, &mb_transport_tls, &t), 0);

    /* Every connection accepted and read from before any hello is sent. */
    struct sockaddr_in a = {.sin_family = AF_INET,
                            .sin_port = htons((uint16_t)mb_server_listen_port(&srv))};
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    for (int i = 0; i < SHAKERS; i++) {
        fd[i] = socket(AF_INET, SOCK_STREAM, 0);
        assert_int_equal(connect(fd[i], (struct sockaddr *)&a, sizeof(a)), 0);
        client[i] = tls_conn_new(cctx, "127.0.0.1");
        assert_non_null(client[i]);
    }
    for (int turn = 0; turn < 1000 && t.stats.handshakes < SHAKERS; turn++)
        uv_run(&loop, UV_RUN_NOWAIT);
    assert_int_equal(t.stats.handshakes, SHAKERS);

    /* Four hellos, all readable by the next turn's poll. */
    for (int i = 0; i < SHAKERS; i++) {
        uint8_t hello[4096];
        assert_int_equal(tls_conn_handshake(client[i]), TLS_AGAIN);
        size_t n = tls_conn_take(client[i], hello, sizeof(hello));
        assert_true(n > 0);
        assert_int_equal(write(fd[i], hello, n), (ssize_t)n);
    }
    unsigned done = 0;
    for (int turn = 0; turn < 50 && done < SHAKERS; turn++) {
        uv_run(&loop, UV_RUN_NOWAIT);
        unsigned now = 0;
        for (int i = 0; i < SHAKERS; i++) {
            struct pollfd p = {.fd = fd[i], .events = POLLIN};
            if (!answered[i] && poll(&p, 1, 0) == 1) {
                answered[i] = true;
                now++;
            }
        }
        assert_true(now <= 1); /* one server flight per turn at most */
        done += now;
    }
    assert_int_equal(done, SHAKERS); /* and every one in its turn */

    for (int i = 0; i < SHAKERS; i++) {
        close(fd[i]);
        tls_conn_free(client[i]);
    }
    tls_context_unref(cctx);
    server_closed = false;
    mb_server_close(&srv, on_server_closed);
    while (!server_closed)
        uv_run(&loop, UV_RUN_ONCE);
    mb_tls_free(&t);
    uv_run(&loop, UV_RUN_DEFAULT); /* the handshake queue's handle closes */
    regmap_image_free(&img);
    regmap_free(&map);
    assert_int_equal(uv_loop_close(&loop), 0);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(role_is_read_from_the_certificate),
        cmocka_unit_test(no_role_reads_empty),
        cmocka_unit_test(roles_taken_or_refused_for_the_real_reason),
        cmocka_unit_test(refusals_say_why),
        cmocka_unit_test(plaintext_is_a_protocol_failure),
        cmocka_unit_test(session_is_resumed),
        cmocka_unit_test(renegotiation_fails_the_connection),
        cmocka_unit_test(fingerprint_pin),
        cmocka_unit_test(client_checks_the_server_name),
        cmocka_unit_test(bad_files_name_their_key),
        cmocka_unit_test(context_outlives_its_owner),
        cmocka_unit_test(handshakes_take_one_step_per_loop_turn),
    };
    return cmocka_run_group_tests(tests, make_pki, remove_pki);
}
