/* SPDX-License-Identifier: MIT */
/* tls.c - see tls.h. */
#include "tls.h"

#include <ctype.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include <openssl/bio.h>
#include <openssl/err.h>
#include <openssl/evp.h>
#include <openssl/objects.h>
#include <openssl/pem.h>
#include <openssl/ssl.h>
#include <openssl/x509.h>
#include <openssl/x509v3.h>

struct tls_context {
    SSL_CTX *ctx;
    int refs;
    bool server;
    bool has_ca;
    bool pin;
    uint8_t fingerprint[32];
    char subject[256];
};

struct tls_conn {
    struct tls_context *ctx;
    SSL *ssl;
    BIO *in;  /* ciphertext from the peer, read by OpenSSL */
    BIO *out; /* ciphertext OpenSSL wrote, for the socket */
    bool handshake_done;
    bool renegotiation; /* the peer tried: refused, and the connection fails */
    enum tls_failure failure;
    char why[200];
    char subject[256];
    char role[TLS_ROLE_MAX];
    bool role_valid;
    char role_problem[64]; /* why not valid; "" */
};

static const char *const failure_names[TLS_FAIL_COUNT] = {
    [TLS_FAIL_NONE] = "none",
    [TLS_FAIL_NO_CERTIFICATE] = "no client certificate",
    [TLS_FAIL_UNTRUSTED] = "certificate not trusted",
    [TLS_FAIL_EXPIRED] = "certificate expired or not yet valid",
    [TLS_FAIL_REVOKED] = "certificate revoked",
    [TLS_FAIL_PROTOCOL] = "protocol",
    [TLS_FAIL_TIMEOUT] = "timeout",
    [TLS_FAIL_OVER_LIMIT] = "too many handshakes",
    [TLS_FAIL_FINGERPRINT] = "fingerprint mismatch",
};

/* Length of the UTF-8 sequence at p (at most 'left' bytes), or 0 when it
 * is not one: overlong forms, surrogates and values past U+10FFFF are not. */
static size_t utf8_sequence(const unsigned char *p, size_t left)
{
    size_t n;
    uint32_t v;

    if (p[0] < 0x80)
        return 1;
    if (p[0] >= 0xC2 && p[0] <= 0xDF)
        n = 2, v = p[0] & 0x1F;
    else if (p[0] >= 0xE0 && p[0] <= 0xEF)
        n = 3, v = p[0] & 0x0F;
    else if (p[0] >= 0xF0 && p[0] <= 0xF4)
        n = 4, v = p[0] & 0x07;
    else
        return 0;
    if (n > left)
        return 0;
    for (size_t i = 1; i < n; i++) {
        if ((p[i] & 0xC0) != 0x80)
            return 0;
        v = v << 6 | (p[i] & 0x3F);
    }
    if ((n == 3 && v < 0x800) || (n == 4 && (v < 0x10000 || v > 0x10FFFF)) ||
        (v >= 0xD800 && v <= 0xDFFF))
        return 0;
    return n;
}

const char *tls_role_name_problem(const char *name, size_t size)
{
    const unsigned char *p = (const unsigned char *)name;

    if (size == 0)
        return "empty";
    if (size >= TLS_ROLE_MAX)
        return "too long";
    for (size_t i = 0; i < size;) {
        size_t n = utf8_sequence(p + i, size - i);
        if (n == 0)
            return "not valid UTF-8";
        /* ASCII controls, space, DEL; C1 controls (U+0080-U+009F);
         * U+00A0 (no-break space). */
        if ((n == 1 && (p[i] <= 0x20 || p[i] == 0x7F)) ||
            (n == 2 && p[i] == 0xC2 && p[i + 1] <= 0xA0))
            return "has a space or a control character";
        i += n;
    }
    return NULL;
}

const char *tls_failure_name(enum tls_failure f)
{
    return f < TLS_FAIL_COUNT ? failure_names[f] : "?";
}

/* OpenSSL's last error as text, and its queue emptied: the queue is the
 * thread's, and a stale entry would be blamed on the next operation. */
static void take_ssl_error(char *buf, size_t size)
{
    unsigned long e = ERR_peek_last_error();

    if (e == 0) {
        snprintf(buf, size, "unknown OpenSSL error");
    } else {
        const char *reason = ERR_reason_error_string(e);
        if (reason)
            snprintf(buf, size, "%s", reason);
        else
            ERR_error_string_n(e, buf, size);
    }
    ERR_clear_error();
}

static void name_line(X509_NAME *name, char *out, size_t size)
{
    BIO *b = BIO_new(BIO_s_mem());
    char *data;
    long n;

    out[0] = '\0';
    if (!b)
        return;
    if (X509_NAME_print_ex(b, name, 0, XN_FLAG_RFC2253 & ~ASN1_STRFLGS_ESC_MSB) >= 0) {
        n = BIO_get_mem_data(b, &data);
        if (n > 0)
            snprintf(out, size, "%.*s", (int)n, data);
    }
    BIO_free(b);
}

int tls_parse_fingerprint(const char *text, uint8_t out[32], char *why, size_t why_size)
{
    unsigned n = 0;

    for (const char *p = text; *p;) {
        if (*p == ':') {
            p++;
            continue;
        }
        if (!isxdigit((unsigned char)p[0]) || !isxdigit((unsigned char)p[1]) || n == 32) {
            snprintf(why, why_size,
                     "must be the certificate's SHA-256 fingerprint: 64 hex digits, "
                     "optionally with ':' between bytes");
            return -EINVAL;
        }
        char byte[3] = {p[0], p[1], '\0'};
        out[n++] = (uint8_t)strtoul(byte, NULL, 16);
        p += 2;
    }
    if (n != 32) {
        snprintf(why, why_size,
                 "must be the certificate's SHA-256 fingerprint: 64 hex digits, "
                 "optionally with ':' between bytes");
        return -EINVAL;
    }
    return 0;
}

/* A file that must exist and be readable; the message names the key. */
static int check_readable(const char *key, const char *path, char *why, size_t why_size)
{
    FILE *f = fopen(path, "r");

    if (!f) {
        int err = errno;
        snprintf(why, why_size, "%s: %s: cannot open: %s", key, path, strerror(err));
        return -err;
    }
    fclose(f);
    return 0;
}

/*
 * A private key readable by anyone but its owner is refused: it has already
 * leaked to every account on the machine. (A systemd credential is 0400.)
 */
static int check_key_mode(const char *key, const char *path, char *why, size_t why_size)
{
    struct stat sb;

    if (stat(path, &sb) != 0) {
        int err = errno;
        snprintf(why, why_size, "%s: %s: %s", key, path, strerror(err));
        return -err;
    }
    if (sb.st_mode & (S_IRWXG | S_IRWXO)) {
        snprintf(why, why_size,
                 "%s: %s is accessible by other users (mode %04o): refused; make it "
                 "readable by its owner only (chmod 600), or pass it as a systemd "
                 "credential (LoadCredential=)",
                 key, path, (unsigned)(sb.st_mode & 07777));
        return -EPERM;
    }
    return 0;
}

/* Loads the CA bundle (and the CRL) into the context's store. */
static int load_trust(SSL_CTX *ctx, const struct tls_settings *s, char *why, size_t why_size)
{
    X509_STORE *store = SSL_CTX_get_cert_store(ctx);
    X509_LOOKUP *lookup = X509_STORE_add_lookup(store, X509_LOOKUP_file());
    char err[160];
    int rc;

    if (!lookup)
        return -ENOMEM;
    rc = check_readable(s->ca_key, s->ca, why, why_size);
    if (rc)
        return rc;
    if (X509_load_cert_file(lookup, s->ca, X509_FILETYPE_PEM) <= 0) {
        take_ssl_error(err, sizeof(err));
        snprintf(why, why_size, "%s: %s: no PEM certificate could be read (%s)", s->ca_key,
                 s->ca, err);
        return -EINVAL;
    }
    if (s->server) {
        /* Tells clients which CAs their certificate must chain to. */
        STACK_OF(X509_NAME) *names = SSL_load_client_CA_file(s->ca);
        if (names)
            SSL_CTX_set_client_CA_list(ctx, names);
        ERR_clear_error();
    }
    if (s->crl && s->crl[0]) {
        rc = check_readable(s->crl_key, s->crl, why, why_size);
        if (rc)
            return rc;
        if (X509_load_crl_file(lookup, s->crl, X509_FILETYPE_PEM) <= 0) {
            take_ssl_error(err, sizeof(err));
            snprintf(why, why_size, "%s: %s: no PEM CRL could be read (%s)", s->crl_key,
                     s->crl, err);
            return -EINVAL;
        }
        /* The peer's own certificate is checked against the CRL. */
        X509_STORE_set_flags(store, X509_V_FLAG_CRL_CHECK);
    }
    return 0;
}

static int load_identity(SSL_CTX *ctx, const struct tls_settings *s, char *why,
                         size_t why_size)
{
    char err[160];
    int rc;

    rc = check_readable(s->certificate_key, s->certificate, why, why_size);
    if (rc)
        return rc;
    if (SSL_CTX_use_certificate_chain_file(ctx, s->certificate) != 1) {
        take_ssl_error(err, sizeof(err));
        snprintf(why, why_size, "%s: %s: not a PEM certificate (%s)", s->certificate_key,
                 s->certificate, err);
        return -EINVAL;
    }
    rc = check_key_mode(s->private_key_key, s->private_key, why, why_size);
    if (rc == 0)
        rc = check_readable(s->private_key_key, s->private_key, why, why_size);
    if (rc)
        return rc;
    if (SSL_CTX_use_PrivateKey_file(ctx, s->private_key, SSL_FILETYPE_PEM) != 1) {
        if (ERR_GET_REASON(ERR_peek_last_error()) == X509_R_KEY_VALUES_MISMATCH ||
            ERR_GET_REASON(ERR_peek_last_error()) == X509_R_KEY_TYPE_MISMATCH) {
            ERR_clear_error();
            snprintf(why, why_size, "%s: %s does not match the certificate of %s (%s)",
                     s->private_key_key, s->private_key, s->certificate_key,
                     s->certificate);
            return -EINVAL;
        }
        take_ssl_error(err, sizeof(err));
        snprintf(why, why_size, "%s: %s: not a PEM private key without a passphrase (%s)",
                 s->private_key_key, s->private_key, err);
        return -EINVAL;
    }
    if (SSL_CTX_check_private_key(ctx) != 1) {
        ERR_clear_error();
        snprintf(why, why_size, "%s: %s does not match the certificate of %s (%s)",
                 s->private_key_key, s->private_key, s->certificate_key, s->certificate);
        return -EINVAL;
    }
    return 0;
}

/*
 * Notes a renegotiation attempt: in TLS 1.2, a ClientHello after the
 * handshake, which OpenSSL 3 refuses with a no_renegotiation alert. The
 * connection is then failed by tls_conn_read(): a peer that tries is not
 * one to go on talking to.
 */
static void on_ssl_info(const SSL *ssl, int where, int ret)
{
    struct tls_conn *c = SSL_get_app_data(ssl);

    if (!c || !c->handshake_done)
        return;
    if ((where & SSL_CB_WRITE_ALERT) && (ret & 0xff) == SSL_AD_NO_RENEGOTIATION)
        c->renegotiation = true;
    if ((where & SSL_CB_HANDSHAKE_START) && SSL_version(ssl) < TLS1_3_VERSION)
        c->renegotiation = true;
}

static const unsigned char session_context[] = "jakagw-mbaps";

int tls_context_new(const struct tls_settings *s, struct tls_context **out, char *why,
                    size_t why_size)
{
    struct tls_context *tc;
    SSL_CTX *ctx;
    int rc;

    *out = NULL;
    if (!s || (s->min_version != 12 && s->min_version != 13)) {
        snprintf(why, why_size, "internal error: bad TLS settings");
        return -EINVAL;
    }
    if (s->server && (!s->certificate || !s->certificate[0] || !s->private_key ||
                      !s->private_key[0] ||
                      (!s->anonymous_clients && (!s->ca || !s->ca[0])))) {
        snprintf(why, why_size, "%s, %s and %s are required", s->certificate_key,
                 s->private_key_key, s->ca_key);
        return -EINVAL;
    }
    if (!s->server && (!s->ca || !s->ca[0]) && (!s->fingerprint || !s->fingerprint[0])) {
        snprintf(why, why_size, "%s or %s is required to trust the server", s->ca_key,
                 s->fingerprint_key);
        return -EINVAL;
    }
    tc = calloc(1, sizeof(*tc));
    if (!tc)
        return -ENOMEM;
    tc->refs = 1;
    tc->server = s->server;
    if (!s->server && s->fingerprint && s->fingerprint[0]) {
        char reason[160];
        if (tls_parse_fingerprint(s->fingerprint, tc->fingerprint, reason, sizeof(reason))) {
            snprintf(why, why_size, "%s: %s", s->fingerprint_key, reason);
            free(tc);
            return -EINVAL;
        }
        tc->pin = true;
    }
    ERR_clear_error();
    ctx = SSL_CTX_new(s->server ? TLS_server_method() : TLS_client_method());
    if (!ctx) {
        free(tc);
        ERR_clear_error();
        return -ENOMEM;
    }
    tc->ctx = ctx;
    SSL_CTX_set_min_proto_version(ctx, s->min_version == 13 ? TLS1_3_VERSION : TLS1_2_VERSION);
    SSL_CTX_set_options(ctx, SSL_OP_NO_COMPRESSION | SSL_OP_NO_RENEGOTIATION |
                                 SSL_OP_CIPHER_SERVER_PREFERENCE);
    /* No SSL_MODE_RELEASE_BUFFERS: a PLC polls, and freeing and taking
     * back the record buffers around every request cost more CPU than
     * plain TCP's whole answer (about 40 KiB per connection kept instead
     * of 28). */
    SSL_CTX_set_info_callback(ctx, on_ssl_info);
    rc = 0;
    if (s->server) {
        rc = load_identity(ctx, s, why, why_size);
        if (rc == 0 && s->ca && s->ca[0])
            rc = load_trust(ctx, s, why, why_size);
        SSL_CTX_set_verify(ctx,
                           s->anonymous_clients
                               ? SSL_VERIFY_NONE
                               : SSL_VERIFY_PEER | SSL_VERIFY_FAIL_IF_NO_PEER_CERT,
                           NULL);
        SSL_CTX_set_session_id_context(ctx, session_context, sizeof(session_context) - 1);
        SSL_CTX_set_session_cache_mode(ctx, SSL_SESS_CACHE_SERVER);
        SSL_CTX_sess_set_cache_size(ctx, 256);
        /* TLS 1.3 tickets would go out alone right after the handshake,
         * and a client that polls its socket before reading (pymodbus)
         * takes a record with no data for a failed read: the ticket goes
         * with the first reply instead (tls_conn_handshake). */
        SSL_CTX_set_num_tickets(ctx, 0);
    } else {
        if (s->ca && s->ca[0]) {
            rc = load_trust(ctx, s, why, why_size);
            tc->has_ca = true;
        }
        if (rc == 0 && s->certificate && s->certificate[0])
            rc = load_identity(ctx, s, why, why_size);
        /* Without a CA, the pin alone decides (after the handshake). */
        SSL_CTX_set_verify(ctx, tc->has_ca ? SSL_VERIFY_PEER : SSL_VERIFY_NONE, NULL);
    }
    if (rc) {
        SSL_CTX_free(ctx);
        free(tc);
        ERR_clear_error();
        return rc;
    }
    X509 *own = SSL_CTX_get0_certificate(ctx);
    if (own)
        name_line(X509_get_subject_name(own), tc->subject, sizeof(tc->subject));
    *out = tc;
    return 0;
}

void tls_context_ref(struct tls_context *ctx)
{
    ctx->refs++;
}

void tls_context_unref(struct tls_context *ctx)
{
    if (!ctx || --ctx->refs > 0)
        return;
    SSL_CTX_free(ctx->ctx);
    free(ctx);
}

const char *tls_context_subject(const struct tls_context *ctx)
{
    return ctx->subject;
}

struct tls_conn *tls_conn_new(struct tls_context *ctx, const char *host)
{
    struct tls_conn *c = calloc(1, sizeof(*c));

    if (!c)
        return NULL;
    c->ssl = SSL_new(ctx->ctx);
    c->in = BIO_new(BIO_s_mem());
    c->out = BIO_new(BIO_s_mem());
    if (!c->ssl || !c->in || !c->out) {
        SSL_free(c->ssl);
        BIO_free(c->in);
        BIO_free(c->out);
        free(c);
        ERR_clear_error();
        return NULL;
    }
    /* An empty input BIO means "more to come", not the end. */
    BIO_set_mem_eof_return(c->in, -1);
    BIO_set_mem_eof_return(c->out, -1);
    SSL_set_bio(c->ssl, c->in, c->out);
    SSL_set_app_data(c->ssl, c);
    c->ctx = ctx;
    tls_context_ref(ctx);
    if (ctx->server) {
        SSL_set_accept_state(c->ssl);
    } else {
        if (host && ctx->has_ca) {
            /* An address is checked as an address, a name as a DNS name. */
            X509_VERIFY_PARAM *param = SSL_get0_param(c->ssl);
            if (X509_VERIFY_PARAM_set1_ip_asc(param, host) != 1) {
                ERR_clear_error();
                SSL_set1_host(c->ssl, host);
                SSL_set_tlsext_host_name(c->ssl, host);
            }
        }
        SSL_set_connect_state(c->ssl);
    }
    ERR_clear_error();
    return c;
}

void tls_conn_free(struct tls_conn *c)
{
    if (!c)
        return;
    SSL_free(c->ssl); /* frees both BIOs */
    tls_context_unref(c->ctx);
    free(c);
}

int tls_conn_feed(struct tls_conn *c, const void *data, size_t size)
{
    if (size == 0)
        return 0;
    if (BIO_write(c->in, data, (int)size) != (int)size) {
        ERR_clear_error();
        return -ENOMEM;
    }
    return 0;
}

static void fail_from_verify(struct tls_conn *c, long vr)
{
    switch (vr) {
    case X509_V_ERR_CERT_HAS_EXPIRED:
    case X509_V_ERR_CERT_NOT_YET_VALID:
        c->failure = TLS_FAIL_EXPIRED;
        break;
    case X509_V_ERR_CERT_REVOKED:
        c->failure = TLS_FAIL_REVOKED;
        break;
    default:
        c->failure = TLS_FAIL_UNTRUSTED;
        break;
    }
    snprintf(c->why, sizeof(c->why), "%s", X509_verify_cert_error_string(vr));
}

static void classify_failure(struct tls_conn *c)
{
    unsigned long e = ERR_peek_last_error();
    long vr = SSL_get_verify_result(c->ssl);
    X509 *peer = SSL_get0_peer_certificate(c->ssl);

    if (ERR_GET_LIB(e) == ERR_LIB_SSL &&
        (ERR_GET_REASON(e) == SSL_R_PEER_DID_NOT_RETURN_A_CERTIFICATE ||
         ERR_GET_REASON(e) == SSL_R_NO_CERTIFICATES_RETURNED)) {
        c->failure = TLS_FAIL_NO_CERTIFICATE;
        snprintf(c->why, sizeof(c->why), "the client sent no certificate");
        ERR_clear_error();
        return;
    }
    if (vr != X509_V_OK && (peer || ERR_GET_REASON(e) == SSL_R_CERTIFICATE_VERIFY_FAILED)) {
        fail_from_verify(c, vr);
        ERR_clear_error();
        return;
    }
    c->failure = TLS_FAIL_PROTOCOL;
    take_ssl_error(c->why, sizeof(c->why));
}

/* The peer's certificate, once trusted: its subject and its role. */
static void read_peer(struct tls_conn *c)
{
    X509 *peer = SSL_get0_peer_certificate(c->ssl);
    ASN1_OBJECT *oid;
    int at;

    c->role_valid = true;
    if (!peer)
        return;
    name_line(X509_get_subject_name(peer), c->subject, sizeof(c->subject));
    oid = OBJ_txt2obj(TLS_ROLE_OID, 1);
    if (!oid) {
        ERR_clear_error();
        return;
    }
    at = X509_get_ext_by_OBJ(peer, oid, -1);
    ASN1_OBJECT_free(oid);
    if (at < 0)
        return;
    X509_EXTENSION *ext = X509_get_ext(peer, at);
    ASN1_OCTET_STRING *der = X509_EXTENSION_get_data(ext);
    const unsigned char *p = ASN1_STRING_get0_data(der);
    ASN1_UTF8STRING *role = d2i_ASN1_UTF8STRING(NULL, &p, ASN1_STRING_length(der));
    c->role_valid = false;
    if (role) {
        int n = ASN1_STRING_length(role);
        const char *text = (const char *)ASN1_STRING_get0_data(role);
        const char *problem = tls_role_name_problem(text, (size_t)n);
        if (!problem) {
            memcpy(c->role, text, (size_t)n);
            c->role[n] = '\0';
            c->role_valid = true;
        } else if (n >= TLS_ROLE_MAX) {
            snprintf(c->role_problem, sizeof(c->role_problem), "too long (%d bytes; at most %d)",
                     n, TLS_ROLE_MAX - 1);
        } else {
            snprintf(c->role_problem, sizeof(c->role_problem), "%s", problem);
        }
        ASN1_UTF8STRING_free(role);
    } else {
        snprintf(c->role_problem, sizeof(c->role_problem), "not a valid UTF8String");
    }
    ERR_clear_error();
}

static bool fingerprint_matches(struct tls_conn *c)
{
    X509 *peer = SSL_get0_peer_certificate(c->ssl);
    unsigned char md[EVP_MAX_MD_SIZE];
    unsigned int len = 0;
    char hex[65];

    if (!peer || X509_digest(peer, EVP_sha256(), md, &len) != 1 || len != 32) {
        ERR_clear_error();
        c->failure = TLS_FAIL_FINGERPRINT;
        snprintf(c->why, sizeof(c->why), "no certificate to compare with tls_fingerprint");
        return false;
    }
    if (memcmp(md, c->ctx->fingerprint, 32) == 0)
        return true;
    for (unsigned i = 0; i < 32; i++)
        snprintf(hex + 2 * i, 3, "%02x", md[i]);
    c->failure = TLS_FAIL_FINGERPRINT;
    snprintf(c->why, sizeof(c->why),
             "the certificate's SHA-256 fingerprint is %s, not the tls_fingerprint pinned",
             hex);
    return false;
}

int tls_conn_handshake(struct tls_conn *c)
{
    int rc;

    if (c->failure != TLS_FAIL_NONE)
        return TLS_ERROR;
    if (c->handshake_done)
        return TLS_OK;
    ERR_clear_error();
    rc = SSL_do_handshake(c->ssl);
    if (rc == 1) {
        if (!c->ctx->server && c->ctx->pin && !fingerprint_matches(c))
            return TLS_ERROR;
        c->handshake_done = true;
        read_peer(c);
        if (c->ctx->server && SSL_version(c->ssl) >= TLS1_3_VERSION)
            SSL_new_session_ticket(c->ssl); /* sent with the next write */
        ERR_clear_error();
        return TLS_OK;
    }
    switch (SSL_get_error(c->ssl, rc)) {
    case SSL_ERROR_WANT_READ:
    case SSL_ERROR_WANT_WRITE:
        return TLS_AGAIN;
    default:
        classify_failure(c);
        return TLS_ERROR;
    }
}

/*
 * SSL_get_error() needs an empty error queue before the call it explains.
 * Every path here empties it after a failure, so on the hot path (a read
 * and a write per Modbus request) it is only looked at: clearing all its
 * slots each time cost more instructions than the record's decryption.
 */
static void clear_stale_errors(void)
{
    if (ERR_peek_error() != 0)
        ERR_clear_error();
}

int tls_conn_read(struct tls_conn *c, void *buf, size_t size)
{
    int n;

    if (c->renegotiation)
        return TLS_ERROR;
    /* Nothing fed and nothing decrypted waiting: asking OpenSSL would only
     * say so, at the cost of a record-layer pass (a request's read loop
     * ends with this call). */
    if (c->handshake_done && BIO_ctrl_pending(c->in) == 0 && !SSL_has_pending(c->ssl))
        return TLS_AGAIN;
    clear_stale_errors();
    n = SSL_read(c->ssl, buf, size > INT32_MAX ? INT32_MAX : (int)size);
    if (c->renegotiation)
        return TLS_ERROR;
    if (n > 0)
        return n;
    switch (SSL_get_error(c->ssl, n)) {
    case SSL_ERROR_WANT_READ:
    case SSL_ERROR_WANT_WRITE:
        return TLS_AGAIN;
    case SSL_ERROR_ZERO_RETURN:
        return TLS_CLOSED;
    default:
        c->failure = TLS_FAIL_PROTOCOL;
        take_ssl_error(c->why, sizeof(c->why));
        return TLS_ERROR;
    }
}

int tls_conn_write(struct tls_conn *c, const void *data, size_t size)
{
    int n;

    if (size == 0)
        return 0;
    clear_stale_errors();
    /* Memory BIOs take everything: one call writes the whole. */
    n = SSL_write(c->ssl, data, (int)size);
    if (n != (int)size) {
        take_ssl_error(c->why, sizeof(c->why));
        return TLS_ERROR;
    }
    return 0;
}

void tls_conn_close_notify(struct tls_conn *c)
{
    if (!c->handshake_done)
        return;
    ERR_clear_error();
    SSL_shutdown(c->ssl);
    ERR_clear_error();
}

size_t tls_conn_pending(const struct tls_conn *c)
{
    return BIO_ctrl_pending(c->out);
}

size_t tls_conn_take(struct tls_conn *c, void *buf, size_t size)
{
    int n = BIO_read(c->out, buf, size > INT32_MAX ? INT32_MAX : (int)size);
    return n > 0 ? (size_t)n : 0;
}

enum tls_failure tls_conn_failure(const struct tls_conn *c, char *why, size_t why_size)
{
    if (why)
        snprintf(why, why_size, "%s", c->renegotiation ? "renegotiation refused" : c->why);
    return c->renegotiation ? TLS_FAIL_PROTOCOL : c->failure;
}

const char *tls_conn_subject(const struct tls_conn *c)
{
    return c->subject;
}

const char *tls_conn_role(const struct tls_conn *c, bool *valid)
{
    if (valid)
        *valid = c->role_valid;
    return c->role;
}

const char *tls_conn_role_problem(const struct tls_conn *c)
{
    return c->role_problem;
}

bool tls_conn_renegotiation_refused(const struct tls_conn *c)
{
    return c->renegotiation;
}

size_t tls_conn_buffered(const struct tls_conn *c)
{
    return BIO_ctrl_pending(c->in);
}

const char *tls_conn_version(const struct tls_conn *c)
{
    return SSL_get_version(c->ssl);
}

bool tls_conn_resumed(const struct tls_conn *c)
{
    return SSL_session_reused(c->ssl) == 1;
}
