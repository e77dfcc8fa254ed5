/*
 * test_vectors.c - host-side test driver for the C codec.
 *
 * Usage: test_vectors <golden.json> [fuzz_bytes]
 *
 * Reads the line-oriented golden-vector file written by firmware_protocol/golden.py
 * (one JSON object per line, see there) and checks, for every vector:
 *   frame   : encode(values) == frame byte-for-byte; decode(frame) == values;
 *             COBS decode/encode against "inner"; the stream decoder returns it;
 *             every single-bit flip of the frame is rejected by the stream decoder.
 *   invalid : fp_decode_frame returns the expected error code.
 *   cobs    : fp_cobs_encode(raw) == encoded and back, too-small buffers refused.
 *   stream  : the byte-by-byte stream decoder returns exactly the expected frames and
 *             ends with the expected counters.
 * With fuzz_bytes, also pushes a random stream of clean frames (from the file), garbage
 * and corrupted frames: every clean frame must be recovered, the buffer stay capped
 * (run it under -fsanitize=address,undefined).
 * Prints "ok frames=N invalid=N streams=N flips=N" and exits 0, or reports the first
 * failures and exits 1. Host-only code: uses stdio/stdlib, unlike the codec.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "furuta_proto.h"

#define LINE_MAX_LEN 262144
#define BYTES_MAX 65536
#define VALUES_MAX 32

static char line[LINE_MAX_LEN];
static uint8_t stream_buf[BYTES_MAX];
static int failures;

static void fail(const char *name, const char *what)
{
    failures++;
    if (failures <= 30) {
        fprintf(stderr, "FAIL %s: %s\n", name, what);
    }
}

/* Pointer just after `"key": ` in line, or NULL. */
static const char *after_key(const char *key)
{
    char pat[64];
    const char *p;
    snprintf(pat, sizeof pat, "\"%s\": ", key);
    p = strstr(line, pat);
    return p ? p + strlen(pat) : NULL;
}

/* Copy the string value of key (up to the closing quote) into out. */
static int get_str(const char *key, char *out, size_t cap)
{
    const char *p = after_key(key);
    size_t n = 0;
    if (!p || *p != '"') {
        return -1;
    }
    p++;
    while (*p && *p != '"' && n + 1 < cap) {
        out[n++] = *p++;
    }
    out[n] = '\0';
    return *p == '"' ? 0 : -1;
}

static int hexval(char c)
{
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

/* Parse a hex string starting at p (ends at '"'); returns byte count or -1. */
static long parse_hex(const char *p, uint8_t *out, size_t cap)
{
    size_t n = 0;
    while (*p && *p != '"') {
        int hi = hexval(p[0]);
        int lo = hexval(p[1]);
        if (hi < 0 || lo < 0 || n >= cap) {
            return -1;
        }
        out[n++] = (uint8_t)(hi * 16 + lo);
        p += 2;
    }
    return (long)n;
}

static long get_hex(const char *key, uint8_t *out, size_t cap)
{
    const char *p = after_key(key);
    if (!p || *p != '"') {
        return -1;
    }
    return parse_hex(p + 1, out, cap);
}

/* Parse the number list of key into vals; returns the count or -1. */
static int get_numbers(const char *key, double *vals, int cap)
{
    const char *p = after_key(key);
    int n = 0;
    if (!p || *p != '[') {
        return -1;
    }
    p++;
    while (*p && *p != ']') {
        char *end;
        if (n >= cap) {
            return -1;
        }
        vals[n++] = strtod(p, &end);
        if (end == p) {
            return -1;
        }
        p = end;
        while (*p == ',' || *p == ' ') {
            p++;
        }
    }
    return n;
}

static int get_number(const char *key, double *v)
{
    const char *p = after_key(key);
    char *end;
    if (!p) {
        return -1;
    }
    *v = strtod(p, &end);
    return end == p ? -1 : 0;
}

/* Build a message from its field values in wire order. Returns 0, or -1 if the
 * type is unknown or the value count is wrong. */
static int msg_from_values(unsigned type, const double *v, int n, fp_msg_t *m)
{
    memset(m, 0, sizeof *m);
    m->type = (uint8_t)type;
    switch (type) {
    case FP_MSG_HELLO:
        if (n != 3) return -1;
        m->u.hello.protocol_version = (uint8_t)v[0];
        m->u.hello.schema_hash = (uint32_t)v[1];
        m->u.hello.nonce = (uint32_t)v[2];
        return 0;
    case FP_MSG_CONFIG:
        if (n != 2) return -1;
        m->u.config.rate_hz = (uint16_t)v[0];
        m->u.config.watchdog_ms = (uint16_t)v[1];
        return 0;
    case FP_MSG_COMMAND:
        if (n != 4) return -1;
        m->u.command.session = (uint32_t)v[0];
        m->u.command.seq = (uint32_t)v[1];
        m->u.command.command = (int16_t)v[2];
        m->u.command.flags = (uint8_t)v[3];
        return 0;
    case FP_MSG_STOP:
        if (n != 1) return -1;
        m->u.stop.reason = (uint8_t)v[0];
        return 0;
    case FP_MSG_HELLO_ACK:
        if (n != 17) return -1;
        m->u.hello_ack.protocol_version = (uint8_t)v[0];
        m->u.hello_ack.schema_hash = (uint32_t)v[1];
        m->u.hello_ack.nonce = (uint32_t)v[2];
        m->u.hello_ack.device_id = (uint32_t)v[3];
        m->u.hello_ack.fw_major = (uint8_t)v[4];
        m->u.hello_ack.fw_minor = (uint8_t)v[5];
        m->u.hello_ack.fw_patch = (uint8_t)v[6];
        m->u.hello_ack.sample_rate_hz = (uint16_t)v[7];
        m->u.hello_ack.watchdog_ms = (uint16_t)v[8];
        m->u.hello_ack.theta_rad_per_count = (float)v[9];
        m->u.hello_ack.theta_offset_counts = (int16_t)v[10];
        m->u.hello_ack.theta_dot_rad_s_per_count = (float)v[11];
        m->u.hello_ack.theta_dot_offset_counts = (int16_t)v[12];
        m->u.hello_ack.phi_counts_per_rev = (uint32_t)v[13];
        m->u.hello_ack.actuator_full_scale = (float)v[14];
        m->u.hello_ack.actuator_kind = (uint8_t)v[15];
        m->u.hello_ack.reset_cause = (uint8_t)v[16];
        return 0;
    case FP_MSG_SAMPLE:
        if (n != 6) return -1;
        m->u.sample.seq = (uint32_t)v[0];
        m->u.sample.t_us = (uint32_t)v[1];
        m->u.sample.theta_adc = (int16_t)v[2];
        m->u.sample.theta_dot_adc = (int16_t)v[3];
        m->u.sample.phi_count = (int32_t)v[4];
        m->u.sample.status = (uint16_t)v[5];
        return 0;
    case FP_MSG_STATUS:
        if (n != 9) return -1;
        m->u.status.flags = (uint16_t)v[0];
        m->u.status.rate_hz = (uint16_t)v[1];
        m->u.status.watchdog_ms = (uint16_t)v[2];
        m->u.status.crc_errors = (uint32_t)v[3];
        m->u.status.frame_errors = (uint32_t)v[4];
        m->u.status.frames_rx = (uint32_t)v[5];
        m->u.status.last_cmd_seq = (uint32_t)v[6];
        m->u.status.uart_overruns = (uint32_t)v[7];
        m->u.status.uart_line_errors = (uint32_t)v[8];
        return 0;
    default:
        return -1;
    }
}

/* Field-wise equality (floats compared bit-for-bit). */
static int msg_equal(const fp_msg_t *a, const fp_msg_t *b)
{
    if (a->type != b->type) {
        return 0;
    }
    switch (a->type) {
    case FP_MSG_HELLO:
        return a->u.hello.protocol_version == b->u.hello.protocol_version &&
               a->u.hello.schema_hash == b->u.hello.schema_hash && a->u.hello.nonce == b->u.hello.nonce;
    case FP_MSG_CONFIG:
        return a->u.config.rate_hz == b->u.config.rate_hz && a->u.config.watchdog_ms == b->u.config.watchdog_ms;
    case FP_MSG_COMMAND:
        return a->u.command.session == b->u.command.session && a->u.command.seq == b->u.command.seq &&
               a->u.command.command == b->u.command.command &&
               a->u.command.flags == b->u.command.flags;
    case FP_MSG_STOP:
        return a->u.stop.reason == b->u.stop.reason;
    case FP_MSG_HELLO_ACK: {
        const fp_hello_ack_t *x = &a->u.hello_ack;
        const fp_hello_ack_t *y = &b->u.hello_ack;
        return x->protocol_version == y->protocol_version && x->schema_hash == y->schema_hash &&
               x->nonce == y->nonce && x->device_id == y->device_id && x->fw_major == y->fw_major &&
               x->fw_minor == y->fw_minor && x->fw_patch == y->fw_patch &&
               x->sample_rate_hz == y->sample_rate_hz && x->watchdog_ms == y->watchdog_ms &&
               memcmp(&x->theta_rad_per_count, &y->theta_rad_per_count, 4) == 0 &&
               x->theta_offset_counts == y->theta_offset_counts &&
               memcmp(&x->theta_dot_rad_s_per_count, &y->theta_dot_rad_s_per_count, 4) == 0 &&
               x->theta_dot_offset_counts == y->theta_dot_offset_counts &&
               x->phi_counts_per_rev == y->phi_counts_per_rev &&
               memcmp(&x->actuator_full_scale, &y->actuator_full_scale, 4) == 0 &&
               x->actuator_kind == y->actuator_kind && x->reset_cause == y->reset_cause;
    }
    case FP_MSG_SAMPLE:
        return a->u.sample.seq == b->u.sample.seq && a->u.sample.t_us == b->u.sample.t_us &&
               a->u.sample.theta_adc == b->u.sample.theta_adc &&
               a->u.sample.theta_dot_adc == b->u.sample.theta_dot_adc &&
               a->u.sample.phi_count == b->u.sample.phi_count && a->u.sample.status == b->u.sample.status;
    case FP_MSG_STATUS:
        return a->u.status.flags == b->u.status.flags && a->u.status.rate_hz == b->u.status.rate_hz &&
               a->u.status.watchdog_ms == b->u.status.watchdog_ms &&
               a->u.status.crc_errors == b->u.status.crc_errors &&
               a->u.status.frame_errors == b->u.status.frame_errors &&
               a->u.status.frames_rx == b->u.status.frames_rx &&
               a->u.status.last_cmd_seq == b->u.status.last_cmd_seq &&
               a->u.status.uart_overruns == b->u.status.uart_overruns &&
               a->u.status.uart_line_errors == b->u.status.uart_line_errors;
    default:
        return 0;
    }
}

static long n_frames, n_invalid, n_streams, n_cobs, n_flips, n_type_seen[256];

#define FUZZ_POOL 64
static fp_msg_t pool_msg[FUZZ_POOL];
static uint8_t pool_wire[FUZZ_POOL][FP_MAX_WIRE_LEN];
static size_t pool_len[FUZZ_POOL];
static int pool_n;

/* Feed bytes to a fresh stream decoder; return the number of messages decoded. */
static int stream_count(const uint8_t *data, size_t len, fp_msg_t *last)
{
    fp_decoder_t d;
    size_t i;
    int got = 0;
    fp_decoder_init(&d);
    for (i = 0; i < len; i++) {
        got += fp_decoder_push(&d, data[i], last);
    }
    return got;
}

static void check_frame(const char *name)
{
    double vals[VALUES_MAX];
    double type_id;
    uint8_t frame[BYTES_MAX], inner[BYTES_MAX], buf[BYTES_MAX], wire[FP_MAX_WIRE_LEN];
    long flen = get_hex("frame", frame, sizeof frame);
    long ilen = get_hex("inner", inner, sizeof inner);
    int nv = get_numbers("values", vals, VALUES_MAX);
    fp_msg_t want, got;
    size_t n, i;
    int bit;

    if (flen <= 0 || ilen <= 0 || nv < 0 || get_number("type_id", &type_id) != 0) {
        fail(name, "unparsable frame vector");
        return;
    }
    if (msg_from_values((unsigned)type_id, vals, nv, &want) != 0) {
        fail(name, "unknown type or wrong value count");
        return;
    }
    n_frames++;
    n_type_seen[want.type]++;

    /* encode: byte-for-byte identical wire frame */
    n = fp_encode(&want, wire, sizeof wire);
    if (n != (size_t)flen + 1u || memcmp(wire, frame, (size_t)flen) != 0 || wire[flen] != 0u) {
        fail(name, "fp_encode differs from golden frame");
    }
    if (fp_encode(&want, wire, (size_t)flen) != 0u) {
        fail(name, "fp_encode ignored a too-small buffer");
    }
    /* decode */
    memset(&got, 0xA5, sizeof got);
    if (fp_decode_frame(frame, (size_t)flen, &got) != FP_OK || !msg_equal(&got, &want)) {
        fail(name, "fp_decode_frame differs from golden values");
    }
    /* COBS layer alone, including in-place decoding */
    if (fp_cobs_decode(frame, (size_t)flen, buf, sizeof buf, &n) != FP_OK || n != (size_t)ilen ||
        memcmp(buf, inner, n) != 0) {
        fail(name, "fp_cobs_decode differs from golden inner frame");
    }
    memcpy(buf, frame, (size_t)flen);
    if (fp_cobs_decode(buf, (size_t)flen, buf, sizeof buf, &n) != FP_OK || n != (size_t)ilen ||
        memcmp(buf, inner, n) != 0) {
        fail(name, "in-place fp_cobs_decode differs");
    }
    n = fp_cobs_encode(inner, (size_t)ilen, buf, sizeof buf);
    if (n != (size_t)flen || memcmp(buf, frame, n) != 0) {
        fail(name, "fp_cobs_encode differs from golden frame");
    }
    if (fp_crc16(inner, (size_t)ilen, FP_CRC_INIT) != 0u) {
        fail(name, "CRC residue of the inner frame is not zero");
    }
    if (pool_n < FUZZ_POOL) {
        pool_msg[pool_n] = want;
        pool_len[pool_n] = fp_encode(&want, pool_wire[pool_n], FP_MAX_WIRE_LEN);
        pool_n++;
    }
    /* stream decoder, and every single-bit flip rejected: 0x00 | frame' | 0x00 */
    buf[0] = 0u;
    memcpy(buf + 1, frame, (size_t)flen);
    buf[flen + 1] = 0u;
    if (stream_count(buf, (size_t)flen + 2u, &got) != 1 || !msg_equal(&got, &want)) {
        fail(name, "stream decoder did not return the frame");
    }
    for (i = 0; i < (size_t)flen; i++) {
        for (bit = 0; bit < 8; bit++) {
            buf[i + 1] = (uint8_t)(buf[i + 1] ^ (1u << bit));
            n_flips++;
            if (stream_count(buf, (size_t)flen + 2u, &got) != 0) {
                fail(name, "a single-bit flip was accepted");
            }
            buf[i + 1] = (uint8_t)(buf[i + 1] ^ (1u << bit));
        }
    }
}

static void check_cobs(const char *name)
{
    static uint8_t raw[BYTES_MAX], enc[BYTES_MAX], buf[BYTES_MAX];
    long rlen = get_hex("raw", raw, sizeof raw);
    long elen = get_hex("encoded", enc, sizeof enc);
    size_t n;
    if (rlen < 0 || elen <= 0) {
        fail(name, "unparsable cobs vector");
        return;
    }
    n_cobs++;
    n = fp_cobs_encode(raw, (size_t)rlen, buf, sizeof buf);
    if (n != (size_t)elen || memcmp(buf, enc, n) != 0) {
        fail(name, "fp_cobs_encode differs");
    }
    if (fp_cobs_encode(raw, (size_t)rlen, buf, (size_t)rlen) != 0u) {
        fail(name, "fp_cobs_encode ignored a too-small buffer");
    }
    if (fp_cobs_decode(enc, (size_t)elen, buf, sizeof buf, &n) != FP_OK || n != (size_t)rlen ||
        memcmp(buf, raw, n) != 0) {
        fail(name, "fp_cobs_decode differs");
    }
    if (rlen > 0 && fp_cobs_decode(enc, (size_t)elen, buf, (size_t)rlen - 1u, &n) != FP_ERR_BUFFER) {
        fail(name, "fp_cobs_decode ignored a too-small buffer");
    }
}

static int error_code(const char *s)
{
    if (strcmp(s, "cobs") == 0) return FP_ERR_COBS;
    if (strcmp(s, "crc") == 0) return FP_ERR_CRC;
    if (strcmp(s, "length") == 0) return FP_ERR_LENGTH;
    if (strcmp(s, "unknown_type") == 0) return FP_ERR_UNKNOWN_TYPE;
    return 1;
}

static void check_invalid(const char *name)
{
    uint8_t frame[BYTES_MAX];
    char err[32];
    fp_msg_t m;
    long flen = get_hex("frame", frame, sizeof frame);
    int rc;
    if (flen < 0 || get_str("error", err, sizeof err) != 0) {
        fail(name, "unparsable invalid vector");
        return;
    }
    n_invalid++;
    rc = fp_decode_frame(frame, (size_t)flen, &m);
    if (rc != error_code(err)) {
        fprintf(stderr, "  %s: got %d, want %s\n", name, rc, err);
        fail(name, "wrong error code");
    }
}

static void check_stream(const char *name)
{
    uint8_t want[FP_MAX_FRAME_LEN + 8], wire[FP_MAX_WIRE_LEN];
    double counters[16];
    const char *p;
    long len = get_hex("stream", stream_buf, sizeof stream_buf);
    int nc = get_numbers("counters", counters, 16);
    fp_decoder_t d;
    fp_msg_t m;
    long i;
    int idx = 0;

    p = after_key("expect");
    if (len < 0 || nc != 8 || !p || *p != '[') {
        fail(name, "unparsable stream vector");
        return;
    }
    p++;
    n_streams++;
    fp_decoder_init(&d);
    for (i = 0; i < len; i++) {
        if (fp_decoder_push(&d, stream_buf[i], &m)) {
            long wlen;
            size_t n = fp_encode(&m, wire, sizeof wire);
            while (*p == ' ' || *p == ',') {
                p++;
            }
            if (*p != '"') {
                fail(name, "decoded more frames than expected");
                return;
            }
            wlen = parse_hex(p + 1, want, sizeof want);
            p = strchr(p + 1, '"') + 1;
            if (wlen < 0 || n != (size_t)wlen + 1u || memcmp(wire, want, (size_t)wlen) != 0) {
                fail(name, "decoded frame differs from the expected one");
            }
            idx++;
        }
    }
    while (*p == ' ' || *p == ',') {
        p++;
    }
    if (*p != ']') {
        fail(name, "decoded fewer frames than expected");
    }
    if ((double)d.frames_ok != counters[0] || (double)d.crc_errors != counters[1] ||
        (double)d.length_errors != counters[2] || (double)d.unknown_type != counters[3] ||
        (double)d.cobs_errors != counters[4] || (double)d.overlong != counters[5] ||
        (double)d.resyncs != counters[6] || (double)d.bytes_discarded != counters[7]) {
        fprintf(stderr, "  %s: C counters %lu %lu %lu %lu %lu %lu %lu %lu\n", name, (unsigned long)d.frames_ok,
                (unsigned long)d.crc_errors, (unsigned long)d.length_errors, (unsigned long)d.unknown_type,
                (unsigned long)d.cobs_errors, (unsigned long)d.overlong, (unsigned long)d.resyncs,
                (unsigned long)d.bytes_discarded);
        fail(name, "stream decoder counters differ");
    }
    (void)idx;
}

static uint32_t rng_state = 2463534242u;

static uint32_t rnd(void) /* xorshift32 */
{
    rng_state ^= rng_state << 13;
    rng_state ^= rng_state >> 17;
    rng_state ^= rng_state << 5;
    return rng_state;
}

/* Random stream of clean frames (0x00 | frame), garbage and corrupted frames pushed byte
 * by byte. Every clean frame must come out at its delimiter; other outputs can only be
 * CRC collisions and are counted. The buffer must never exceed its cap. */
static void fuzz(long nbytes)
{
    fp_decoder_t d;
    fp_msg_t m;
    long pushed = 0, clean = 0, collisions = 0;
    uint8_t tmp[FP_MAX_WIRE_LEN];
    fp_decoder_init(&d);
    if (pool_n == 0) {
        fail("fuzz", "no frames to fuzz with");
        return;
    }
    while (pushed < nbytes) {
        uint32_t r = rnd() % 10u;
        int k = (int)(rnd() % (uint32_t)pool_n);
        size_t i, len;
        if (r < 5u) { /* clean frame after a delimiter */
            int got = fp_decoder_push(&d, 0u, &m);
            collisions += got;
            for (i = 0; i < pool_len[k]; i++) {
                got = fp_decoder_push(&d, pool_wire[k][i], &m);
                if (i + 1u < pool_len[k]) {
                    collisions += got;
                } else if (!got || !msg_equal(&m, &pool_msg[k])) {
                    fail("fuzz", "clean frame not recovered");
                }
            }
            pushed += (long)pool_len[k] + 1;
            clean++;
        } else if (r < 8u) { /* garbage */
            len = 1u + rnd() % 80u;
            for (i = 0; i < len; i++) {
                collisions += fp_decoder_push(&d, (uint8_t)(rnd() & (r == 5u ? 0xFFu : 0x07u)), &m);
            }
            pushed += (long)len;
        } else { /* corrupted frame: 1-3 bit flips, maybe truncated */
            unsigned flips = 1u + rnd() % 3u;
            len = pool_len[k];
            memcpy(tmp, pool_wire[k], len);
            while (flips--) {
                i = rnd() % len;
                tmp[i] = (uint8_t)(tmp[i] ^ (1u << (rnd() % 8u)));
            }
            if (memcmp(tmp, pool_wire[k], len) == 0) {
                continue; /* flips cancelled out: not corrupted */
            }
            if (r == 9u) {
                len = 1u + rnd() % (len - 2u); /* truncated: loses >= 1 content byte and the delimiter */
            }
            for (i = 0; i < len; i++) {
                collisions += fp_decoder_push(&d, tmp[i], &m);
            }
            pushed += (long)len;
        }
        if (d.len > sizeof d.buf) {
            fail("fuzz", "decoder buffer overflow");
            return;
        }
    }
    printf("fuzz bytes=%ld clean_frames=%ld collisions=%ld frames_ok=%lu crc_errors=%lu cobs_errors=%lu "
           "length_errors=%lu overlong=%lu\n",
           pushed, clean, collisions, (unsigned long)d.frames_ok, (unsigned long)d.crc_errors,
           (unsigned long)d.cobs_errors, (unsigned long)d.length_errors, (unsigned long)d.overlong);
    if (collisions > 10 + (long)(d.crc_errors / 16384u)) {
        fail("fuzz", "implausibly many corrupted frames accepted");
    }
}

int main(int argc, char **argv)
{
    FILE *f;
    double v;
    int seen_version = 0, seen_hash = 0;
    static const uint8_t check[] = "123456789";

    if (argc != 2 && argc != 3) {
        fprintf(stderr, "usage: %s golden.json [fuzz_bytes]\n", argv[0]);
        return 2;
    }
    if (fp_crc16(check, 9, FP_CRC_INIT) != 0x29B1u) {
        fail("crc16", "check value of \"123456789\" is not 0x29B1");
    }
    f = fopen(argv[1], "r");
    if (!f) {
        perror(argv[1]);
        return 2;
    }
    while (fgets(line, sizeof line, f)) {
        char kind[16], name[128];
        if (strlen(line) == sizeof line - 1u) {
            fail("parser", "line too long");
            break;
        }
        if (strncmp(line, "\"protocol_version\": ", 20) == 0 && get_number("protocol_version", &v) == 0) {
            seen_version = 1;
            if (v != (double)FP_PROTOCOL_VERSION) fail("header", "FP_PROTOCOL_VERSION differs from vectors");
            continue;
        }
        if (strncmp(line, "\"schema_hash\": ", 15) == 0 && get_number("schema_hash", &v) == 0) {
            seen_hash = 1;
            if (v != (double)FP_SCHEMA_HASH) fail("header", "FP_SCHEMA_HASH differs from vectors");
            continue;
        }
        if (get_str("kind", kind, sizeof kind) != 0) {
            continue;
        }
        if (get_str("name", name, sizeof name) != 0) {
            fail("parser", "vector without name");
            continue;
        }
        if (strcmp(kind, "frame") == 0) {
            check_frame(name);
        } else if (strcmp(kind, "invalid") == 0) {
            check_invalid(name);
        } else if (strcmp(kind, "stream") == 0) {
            check_stream(name);
        } else if (strcmp(kind, "cobs") == 0) {
            check_cobs(name);
        } else {
            fail(name, "unknown vector kind");
        }
    }
    fclose(f);
    if (!seen_version || !seen_hash) {
        fail("header", "protocol_version or schema_hash missing");
    }
    if (n_frames == 0) {
        fail("parser", "no frame vectors found");
    }
    if (argc == 3) {
        fuzz(strtol(argv[2], NULL, 10));
    }
    if (failures) {
        fprintf(stderr, "%d failure(s)\n", failures);
        return 1;
    }
    printf("ok frames=%ld invalid=%ld streams=%ld cobs=%ld flips=%ld types=", n_frames, n_invalid, n_streams,
           n_cobs, n_flips);
    {
        int t, first = 1;
        for (t = 0; t < 256; t++) {
            if (n_type_seen[t]) {
                printf(first ? "%d" : ",%d", t);
                first = 0;
            }
        }
    }
    printf("\n");
    return 0;
}
