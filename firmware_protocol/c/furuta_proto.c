/*
 * furuta_proto.c - C99 codec of the Furuta DAQ serial protocol. See furuta_proto.h.
 */
#include "furuta_proto.h"

#include <string.h> /* memcpy only */

/* C99 compile-time check: floats must be 4 bytes (IEEE-754 binary32 is assumed). */
typedef char fp_float_is_4_bytes[(sizeof(float) == 4u) ? 1 : -1];

/* ---- CRC ------------------------------------------------------------------------------- */

/* CRC-16/CCITT-FALSE of one byte value v (crc_table[v] = crc of v << 8 with init 0): one lookup per
 * byte instead of eight shift steps (the firmware's tick decodes and encodes ~100 bytes). */
static const uint16_t crc_table[256] = {
    0x0000u, 0x1021u, 0x2042u, 0x3063u, 0x4084u, 0x50A5u, 0x60C6u, 0x70E7u,
    0x8108u, 0x9129u, 0xA14Au, 0xB16Bu, 0xC18Cu, 0xD1ADu, 0xE1CEu, 0xF1EFu,
    0x1231u, 0x0210u, 0x3273u, 0x2252u, 0x52B5u, 0x4294u, 0x72F7u, 0x62D6u,
    0x9339u, 0x8318u, 0xB37Bu, 0xA35Au, 0xD3BDu, 0xC39Cu, 0xF3FFu, 0xE3DEu,
    0x2462u, 0x3443u, 0x0420u, 0x1401u, 0x64E6u, 0x74C7u, 0x44A4u, 0x5485u,
    0xA56Au, 0xB54Bu, 0x8528u, 0x9509u, 0xE5EEu, 0xF5CFu, 0xC5ACu, 0xD58Du,
    0x3653u, 0x2672u, 0x1611u, 0x0630u, 0x76D7u, 0x66F6u, 0x5695u, 0x46B4u,
    0xB75Bu, 0xA77Au, 0x9719u, 0x8738u, 0xF7DFu, 0xE7FEu, 0xD79Du, 0xC7BCu,
    0x48C4u, 0x58E5u, 0x6886u, 0x78A7u, 0x0840u, 0x1861u, 0x2802u, 0x3823u,
    0xC9CCu, 0xD9EDu, 0xE98Eu, 0xF9AFu, 0x8948u, 0x9969u, 0xA90Au, 0xB92Bu,
    0x5AF5u, 0x4AD4u, 0x7AB7u, 0x6A96u, 0x1A71u, 0x0A50u, 0x3A33u, 0x2A12u,
    0xDBFDu, 0xCBDCu, 0xFBBFu, 0xEB9Eu, 0x9B79u, 0x8B58u, 0xBB3Bu, 0xAB1Au,
    0x6CA6u, 0x7C87u, 0x4CE4u, 0x5CC5u, 0x2C22u, 0x3C03u, 0x0C60u, 0x1C41u,
    0xEDAEu, 0xFD8Fu, 0xCDECu, 0xDDCDu, 0xAD2Au, 0xBD0Bu, 0x8D68u, 0x9D49u,
    0x7E97u, 0x6EB6u, 0x5ED5u, 0x4EF4u, 0x3E13u, 0x2E32u, 0x1E51u, 0x0E70u,
    0xFF9Fu, 0xEFBEu, 0xDFDDu, 0xCFFCu, 0xBF1Bu, 0xAF3Au, 0x9F59u, 0x8F78u,
    0x9188u, 0x81A9u, 0xB1CAu, 0xA1EBu, 0xD10Cu, 0xC12Du, 0xF14Eu, 0xE16Fu,
    0x1080u, 0x00A1u, 0x30C2u, 0x20E3u, 0x5004u, 0x4025u, 0x7046u, 0x6067u,
    0x83B9u, 0x9398u, 0xA3FBu, 0xB3DAu, 0xC33Du, 0xD31Cu, 0xE37Fu, 0xF35Eu,
    0x02B1u, 0x1290u, 0x22F3u, 0x32D2u, 0x4235u, 0x5214u, 0x6277u, 0x7256u,
    0xB5EAu, 0xA5CBu, 0x95A8u, 0x8589u, 0xF56Eu, 0xE54Fu, 0xD52Cu, 0xC50Du,
    0x34E2u, 0x24C3u, 0x14A0u, 0x0481u, 0x7466u, 0x6447u, 0x5424u, 0x4405u,
    0xA7DBu, 0xB7FAu, 0x8799u, 0x97B8u, 0xE75Fu, 0xF77Eu, 0xC71Du, 0xD73Cu,
    0x26D3u, 0x36F2u, 0x0691u, 0x16B0u, 0x6657u, 0x7676u, 0x4615u, 0x5634u,
    0xD94Cu, 0xC96Du, 0xF90Eu, 0xE92Fu, 0x99C8u, 0x89E9u, 0xB98Au, 0xA9ABu,
    0x5844u, 0x4865u, 0x7806u, 0x6827u, 0x18C0u, 0x08E1u, 0x3882u, 0x28A3u,
    0xCB7Du, 0xDB5Cu, 0xEB3Fu, 0xFB1Eu, 0x8BF9u, 0x9BD8u, 0xABBBu, 0xBB9Au,
    0x4A75u, 0x5A54u, 0x6A37u, 0x7A16u, 0x0AF1u, 0x1AD0u, 0x2AB3u, 0x3A92u,
    0xFD2Eu, 0xED0Fu, 0xDD6Cu, 0xCD4Du, 0xBDAAu, 0xAD8Bu, 0x9DE8u, 0x8DC9u,
    0x7C26u, 0x6C07u, 0x5C64u, 0x4C45u, 0x3CA2u, 0x2C83u, 0x1CE0u, 0x0CC1u,
    0xEF1Fu, 0xFF3Eu, 0xCF5Du, 0xDF7Cu, 0xAF9Bu, 0xBFBAu, 0x8FD9u, 0x9FF8u,
    0x6E17u, 0x7E36u, 0x4E55u, 0x5E74u, 0x2E93u, 0x3EB2u, 0x0ED1u, 0x1EF0u,
};

uint16_t fp_crc16(const uint8_t *data, size_t len, uint16_t crc)
{
    size_t i;
    for (i = 0; i < len; i++) {
        crc = (uint16_t)((crc << 8) ^ crc_table[(crc >> 8) ^ data[i]]);
    }
    return crc;
}

/* ---- COBS ------------------------------------------------------------------------------ */

size_t fp_cobs_encode(const uint8_t *in, size_t len, uint8_t *out, size_t cap)
{
    size_t code_pos = 0; /* where the current group's code byte goes */
    size_t o = 1;        /* next output position */
    uint8_t code = 1;    /* 1 + data bytes in the current group */
    size_t i;

    if (cap < len + len / 254u + 1u) {
        return 0;
    }
    for (i = 0; i < len; i++) {
        if (in[i] != 0u) {
            out[o++] = in[i];
            code++;
        }
        if (in[i] == 0u || code == 0xFFu) { /* zero, or a full 254-byte group: close it */
            out[code_pos] = code;
            code = 1;
            code_pos = o;
            if (in[i] == 0u || i + 1u < len) {
                o++; /* reserve the next code byte (not after a final full group) */
            }
        }
    }
    if (code_pos < o) {
        out[code_pos] = code;
    }
    return o;
}

int fp_cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t cap, size_t *out_len)
{
    size_t i = 0;
    size_t o = 0;
    *out_len = 0;
    if (len == 0u) {
        return FP_ERR_COBS;
    }
    while (i < len) {
        uint8_t code = in[i];
        size_t end;
        if (code == 0u || (size_t)code > len - i) {
            return FP_ERR_COBS; /* delimiter inside, or group runs past the end */
        }
        end = i + code;
        for (i = i + 1u; i < end; i++) {
            if (in[i] == 0u) {
                return FP_ERR_COBS;
            }
            if (o >= cap) {
                return FP_ERR_BUFFER;
            }
            out[o++] = in[i]; /* o < i always, so in-place decoding is safe */
        }
        if (code != 0xFFu && i < len) {
            if (o >= cap) {
                return FP_ERR_BUFFER;
            }
            out[o++] = 0u;
        }
    }
    *out_len = o;
    return FP_OK;
}

/* ---- little-endian field access ---------------------------------------------------------- */

static void put_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)(v >> 8);
}

static void put_u32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)((v >> 8) & 0xFFu);
    p[2] = (uint8_t)((v >> 16) & 0xFFu);
    p[3] = (uint8_t)(v >> 24);
}

static void put_i16(uint8_t *p, int16_t v) { put_u16(p, (uint16_t)v); }
static void put_i32(uint8_t *p, int32_t v) { put_u32(p, (uint32_t)v); }

static void put_f32(uint8_t *p, float v)
{
    uint32_t bits;
    memcpy(&bits, &v, sizeof bits);
    put_u32(p, bits);
}

static uint16_t get_u16(const uint8_t *p) { return (uint16_t)(p[0] | ((uint16_t)p[1] << 8)); }

static uint32_t get_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

static int16_t get_i16(const uint8_t *p)
{
    uint16_t u = get_u16(p);
    return (int16_t)(u >= 0x8000u ? (int32_t)u - 0x10000 : (int32_t)u);
}

static int32_t get_i32(const uint8_t *p)
{
    uint32_t u = get_u32(p);
    return u >= 0x80000000u ? (int32_t)(u - 0x80000000u) - (int32_t)0x7FFFFFFF - 1 : (int32_t)u;
}

static float get_f32(const uint8_t *p)
{
    uint32_t bits = get_u32(p);
    float v;
    memcpy(&v, &bits, sizeof v);
    return v;
}

/* ---- message bodies ----------------------------------------------------------------------- */

size_t fp_body_size(uint8_t type)
{
    switch (type) {
    case FP_MSG_HELLO: return FP_BODY_HELLO;
    case FP_MSG_CONFIG: return FP_BODY_CONFIG;
    case FP_MSG_COMMAND: return FP_BODY_COMMAND;
    case FP_MSG_STOP: return FP_BODY_STOP;
    case FP_MSG_HELLO_ACK: return FP_BODY_HELLO_ACK;
    case FP_MSG_SAMPLE: return FP_BODY_SAMPLE;
    case FP_MSG_STATUS: return FP_BODY_STATUS;
    default: return 0;
    }
}

/* Write the body of msg at b (fp_body_size(msg->type) bytes). */
static void pack_body(const fp_msg_t *msg, uint8_t *b)
{
    switch (msg->type) {
    case FP_MSG_HELLO: {
        const fp_hello_t *m = &msg->u.hello;
        b[0] = m->protocol_version;
        put_u32(b + 1, m->schema_hash);
        put_u32(b + 5, m->nonce);
        break;
    }
    case FP_MSG_CONFIG:
        put_u16(b, msg->u.config.rate_hz);
        put_u16(b + 2, msg->u.config.watchdog_ms);
        break;
    case FP_MSG_COMMAND:
        put_u32(b, msg->u.command.session);
        put_u32(b + 4, msg->u.command.seq);
        put_i16(b + 8, msg->u.command.command);
        b[10] = msg->u.command.flags;
        break;
    case FP_MSG_STOP:
        b[0] = msg->u.stop.reason;
        break;
    case FP_MSG_HELLO_ACK: {
        const fp_hello_ack_t *m = &msg->u.hello_ack;
        b[0] = m->protocol_version;
        put_u32(b + 1, m->schema_hash);
        put_u32(b + 5, m->nonce);
        put_u32(b + 9, m->device_id);
        b[13] = m->fw_major;
        b[14] = m->fw_minor;
        b[15] = m->fw_patch;
        put_u16(b + 16, m->sample_rate_hz);
        put_u16(b + 18, m->watchdog_ms);
        put_f32(b + 20, m->theta_rad_per_count);
        put_i16(b + 24, m->theta_offset_counts);
        put_f32(b + 26, m->theta_dot_rad_s_per_count);
        put_i16(b + 30, m->theta_dot_offset_counts);
        put_u32(b + 32, m->phi_counts_per_rev);
        put_f32(b + 36, m->actuator_full_scale);
        b[40] = m->actuator_kind;
        b[41] = m->reset_cause;
        break;
    }
    case FP_MSG_SAMPLE: {
        const fp_sample_t *m = &msg->u.sample;
        put_u32(b, m->seq);
        put_u32(b + 4, m->t_us);
        put_i16(b + 8, m->theta_adc);
        put_i16(b + 10, m->theta_dot_adc);
        put_i32(b + 12, m->phi_count);
        put_u16(b + 16, m->status);
        break;
    }
    case FP_MSG_STATUS: {
        const fp_status_t *m = &msg->u.status;
        put_u16(b, m->flags);
        put_u16(b + 2, m->rate_hz);
        put_u16(b + 4, m->watchdog_ms);
        put_u32(b + 6, m->crc_errors);
        put_u32(b + 10, m->frame_errors);
        put_u32(b + 14, m->frames_rx);
        put_u32(b + 18, m->last_cmd_seq);
        put_u32(b + 22, m->uart_overruns);
        put_u32(b + 26, m->uart_line_errors);
        break;
    }
    default:
        break;
    }
}

/* Fill msg from the body at b; msg->type must already be set to a known type. */
static void unpack_body(const uint8_t *b, fp_msg_t *msg)
{
    switch (msg->type) {
    case FP_MSG_HELLO: {
        fp_hello_t *m = &msg->u.hello;
        m->protocol_version = b[0];
        m->schema_hash = get_u32(b + 1);
        m->nonce = get_u32(b + 5);
        break;
    }
    case FP_MSG_CONFIG:
        msg->u.config.rate_hz = get_u16(b);
        msg->u.config.watchdog_ms = get_u16(b + 2);
        break;
    case FP_MSG_COMMAND:
        msg->u.command.session = get_u32(b);
        msg->u.command.seq = get_u32(b + 4);
        msg->u.command.command = get_i16(b + 8);
        msg->u.command.flags = b[10];
        break;
    case FP_MSG_STOP:
        msg->u.stop.reason = b[0];
        break;
    case FP_MSG_HELLO_ACK: {
        fp_hello_ack_t *m = &msg->u.hello_ack;
        m->protocol_version = b[0];
        m->schema_hash = get_u32(b + 1);
        m->nonce = get_u32(b + 5);
        m->device_id = get_u32(b + 9);
        m->fw_major = b[13];
        m->fw_minor = b[14];
        m->fw_patch = b[15];
        m->sample_rate_hz = get_u16(b + 16);
        m->watchdog_ms = get_u16(b + 18);
        m->theta_rad_per_count = get_f32(b + 20);
        m->theta_offset_counts = get_i16(b + 24);
        m->theta_dot_rad_s_per_count = get_f32(b + 26);
        m->theta_dot_offset_counts = get_i16(b + 30);
        m->phi_counts_per_rev = get_u32(b + 32);
        m->actuator_full_scale = get_f32(b + 36);
        m->actuator_kind = b[40];
        m->reset_cause = b[41];
        break;
    }
    case FP_MSG_SAMPLE: {
        fp_sample_t *m = &msg->u.sample;
        m->seq = get_u32(b);
        m->t_us = get_u32(b + 4);
        m->theta_adc = get_i16(b + 8);
        m->theta_dot_adc = get_i16(b + 10);
        m->phi_count = get_i32(b + 12);
        m->status = get_u16(b + 16);
        break;
    }
    case FP_MSG_STATUS: {
        fp_status_t *m = &msg->u.status;
        m->flags = get_u16(b);
        m->rate_hz = get_u16(b + 2);
        m->watchdog_ms = get_u16(b + 4);
        m->crc_errors = get_u32(b + 6);
        m->frame_errors = get_u32(b + 10);
        m->frames_rx = get_u32(b + 14);
        m->last_cmd_seq = get_u32(b + 18);
        m->uart_overruns = get_u32(b + 22);
        m->uart_line_errors = get_u32(b + 26);
        break;
    }
    default:
        break;
    }
}

/* ---- frames ---------------------------------------------------------------------------------- */

size_t fp_encode(const fp_msg_t *msg, uint8_t *out, size_t cap)
{
    uint8_t inner[FP_MAX_INNER_LEN];
    size_t body = fp_body_size(msg->type);
    size_t n;
    uint16_t crc;

    if (body == 0u || cap < body + 5u) { /* cobs code + type + body + crc + delimiter */
        return 0;
    }
    inner[0] = msg->type;
    pack_body(msg, inner + 1);
    crc = fp_crc16(inner, body + 1u, FP_CRC_INIT);
    inner[body + 1u] = (uint8_t)(crc >> 8); /* big-endian */
    inner[body + 2u] = (uint8_t)(crc & 0xFFu);
    n = fp_cobs_encode(inner, body + 3u, out, cap - 1u);
    if (n == 0u) {
        return 0;
    }
    out[n] = 0u;
    return n + 1u;
}

int fp_decode_frame(const uint8_t *frame, size_t len, fp_msg_t *msg)
{
    uint8_t inner[FP_MAX_INNER_LEN];
    size_t n = 0;
    size_t body;
    int rc;

    if (len > FP_MAX_FRAME_LEN) {
        return FP_ERR_LENGTH;
    }
    rc = fp_cobs_decode(frame, len, inner, sizeof inner, &n);
    if (rc == FP_ERR_BUFFER) {
        return FP_ERR_LENGTH;
    }
    if (rc != FP_OK) {
        return rc;
    }
    if (n < 3u) {
        return FP_ERR_LENGTH;
    }
    if (fp_crc16(inner, n, FP_CRC_INIT) != 0u) {
        return FP_ERR_CRC;
    }
    body = fp_body_size(inner[0]);
    if (body == 0u) {
        return FP_ERR_UNKNOWN_TYPE;
    }
    if (n != body + 3u) {
        return FP_ERR_LENGTH;
    }
    msg->type = inner[0];
    unpack_body(inner + 1, msg);
    return FP_OK;
}

/* ---- stream decoder ----------------------------------------------------------------------- */

void fp_decoder_init(fp_decoder_t *d)
{
    d->len = 0;
    d->skipping = 0;
    d->lost = 0;
    d->frames_ok = 0;
    d->crc_errors = 0;
    d->length_errors = 0;
    d->unknown_type = 0;
    d->cobs_errors = 0;
    d->overlong = 0;
    d->resyncs = 0;
    d->bytes_discarded = 0;
}

int fp_decoder_push(fp_decoder_t *d, uint8_t byte, fp_msg_t *msg)
{
    size_t n;
    int rc;

    if (byte != 0u) {
        if (d->skipping) {
            d->bytes_discarded++;
        } else if (d->len < sizeof d->buf) {
            d->buf[d->len++] = byte;
        } else { /* over-long: drop and discard up to the next delimiter */
            d->overlong++;
            d->bytes_discarded += (uint32_t)d->len + 1u;
            d->len = 0;
            d->skipping = 1;
            d->lost = 1;
        }
        return 0;
    }
    /* delimiter */
    d->skipping = 0;
    n = d->len;
    d->len = 0;
    if (n == 0u) {
        return 0; /* empty frame: idle fill, ignored */
    }
    rc = fp_decode_frame(d->buf, n, msg);
    if (rc == FP_OK) {
        d->frames_ok++;
        if (d->lost) {
            d->resyncs++;
            d->lost = 0;
        }
        return 1;
    }
    switch (rc) {
    case FP_ERR_CRC: d->crc_errors++; break;
    case FP_ERR_LENGTH: d->length_errors++; break;
    case FP_ERR_UNKNOWN_TYPE: d->unknown_type++; break;
    default: d->cobs_errors++; break;
    }
    d->bytes_discarded += (uint32_t)n;
    d->lost = 1;
    return 0;
}
