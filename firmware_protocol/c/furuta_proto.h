/*
 * furuta_proto.h - C99 codec of the Furuta DAQ serial protocol (firmware side).
 *
 * Specification: firmware_protocol/PROTOCOL.md. The Python codec (firmware_protocol/)
 * is the reference; both are tested against firmware_protocol/vectors/golden.json.
 *
 * Wire frame:  COBS( type | body | crc16 ) 0x00
 *   type   u8, message id (FP_MSG_*); bit 7 set = device -> host
 *   body   fixed size per type, little-endian, no padding
 *   crc16  CRC-16/CCITT-FALSE over type|body, stored BIG-endian, so the CRC of the
 *          whole decoded frame is 0
 *
 * No dynamic memory, no libc beyond memcpy (string.h); stdint.h/stddef.h only.
 * Floats are IEEE-754 binary32, copied bit-for-bit (the target must use IEEE floats).
 * All functions are reentrant; a decoder instance must not be shared between contexts
 * without external locking.
 */
#ifndef FURUTA_PROTO_H
#define FURUTA_PROTO_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* ---- protocol identity (checked at handshake) --------------------------------------- */
#define FP_PROTOCOL_VERSION 2u
/* Hash of the message definitions; must equal firmware_protocol.SCHEMA_HASH.
 * The test suite checks it against vectors/golden.json. */
#define FP_SCHEMA_HASH 0xBDD6DF13u

#define FP_COMMAND_FULL_SCALE 32767 /* COMMAND.command counts at actuator full scale */
#define FP_DEFAULT_WATCHDOG_MS 20u
#define FP_CRC_INIT 0xFFFFu

/* ---- message type ids ---------------------------------------------------------------- */
#define FP_MSG_HELLO 0x01u     /* host -> device */
#define FP_MSG_CONFIG 0x02u    /* host -> device */
#define FP_MSG_COMMAND 0x03u   /* host -> device */
#define FP_MSG_STOP 0x04u      /* host -> device */
#define FP_MSG_HELLO_ACK 0x81u /* device -> host */
#define FP_MSG_SAMPLE 0x82u    /* device -> host */
#define FP_MSG_STATUS 0x83u    /* device -> host */

/* ---- body sizes in bytes (without type byte and CRC) --------------------------------- */
#define FP_BODY_HELLO 9u
#define FP_BODY_CONFIG 4u
#define FP_BODY_COMMAND 11u
#define FP_BODY_STOP 1u
#define FP_BODY_HELLO_ACK 42u
#define FP_BODY_SAMPLE 18u
#define FP_BODY_STATUS 30u

#define FP_MAX_INNER_LEN (1u + FP_BODY_HELLO_ACK + 2u) /* largest type|body|crc: 45 */
#define FP_MAX_FRAME_LEN (FP_MAX_INNER_LEN + 1u)       /* largest COBS frame, no delimiter: 46 */
#define FP_MAX_WIRE_LEN (FP_MAX_FRAME_LEN + 1u)        /* with the 0x00 delimiter: TX buffer size */

/* ---- status flags (SAMPLE.status, STATUS.flags) -------------------------------------- */
#define FP_ST_WATCHDOG_TRIPPED 0x0001u /* latched fault */
#define FP_ST_ADC_OVERRANGE 0x0002u    /* latched fault */
#define FP_ST_ENCODER_ERROR 0x0004u    /* latched fault */
#define FP_ST_CRC_ERROR 0x0008u        /* >= 1 rejected incoming frame since previous SAMPLE */
#define FP_ST_ENABLED 0x0010u          /* actuator output live */
#define FP_ST_COMMAND_LATE 0x0020u     /* no COMMAND answering the previous SAMPLE before this tick */
#define FP_ST_TICK_OVERRUN 0x0040u     /* a tick deadline was missed */
#define FP_ST_CONFIG_REJECTED 0x0080u  /* last CONFIG out of range, not applied */
#define FP_ST_TX_OVERFLOW 0x0100u      /* outgoing frames were dropped */
#define FP_ST_FAULT_MASK (FP_ST_WATCHDOG_TRIPPED | FP_ST_ADC_OVERRANGE | FP_ST_ENCODER_ERROR)

/* ---- command flags (COMMAND.flags) ---------------------------------------------------- */
#define FP_CMD_ENABLE 0x01u      /* drive the actuator; clear: output zero */
#define FP_CMD_CLEAR_FAULT 0x02u /* clear latched faults; output zero on that tick */

/* ---- actuator kind (HELLO_ACK.actuator_kind) ------------------------------------------ */
#define FP_ACT_TORQUE_NM 0u
#define FP_ACT_VOLTAGE_V 1u

/* ---- reset cause (HELLO_ACK.reset_cause) ----------------------------------------------- */
#define FP_RESET_UNKNOWN 0u
#define FP_RESET_POWER_ON 1u /* power-on or brown-out */
#define FP_RESET_PIN 2u      /* the reset pin (button, debugger) */
#define FP_RESET_WATCHDOG 3u /* the hardware watchdog: the firmware hung */
#define FP_RESET_SOFTWARE 4u /* the firmware asked for it */
#define FP_RESET_FAULT 5u    /* the fault handler took the drive off and let the watchdog reset */

/* ---- messages -------------------------------------------------------------------------- */
typedef struct {
    uint8_t protocol_version;
    uint32_t schema_hash;
    uint32_t nonce;
} fp_hello_t;

typedef struct {
    uint8_t protocol_version;
    uint32_t schema_hash;
    uint32_t nonce; /* echo of HELLO.nonce */
    uint32_t device_id;
    uint8_t fw_major;
    uint8_t fw_minor;
    uint8_t fw_patch;
    uint16_t sample_rate_hz;
    uint16_t watchdog_ms;
    float theta_rad_per_count;
    int16_t theta_offset_counts;
    float theta_dot_rad_s_per_count;
    int16_t theta_dot_offset_counts;
    uint32_t phi_counts_per_rev;
    float actuator_full_scale; /* N m or V at COMMAND.command == FP_COMMAND_FULL_SCALE */
    uint8_t actuator_kind;     /* FP_ACT_* */
    uint8_t reset_cause;       /* FP_RESET_*: what started the firmware that answers */
} fp_hello_ack_t;

typedef struct {
    uint16_t rate_hz;
    uint16_t watchdog_ms;
} fp_config_t;

typedef struct {
    uint32_t session; /* nonce of the HELLO that started the session: another session's COMMAND is discarded */
    uint32_t seq;    /* seq of the SAMPLE this command answers */
    int16_t command; /* actuator command, +-FP_COMMAND_FULL_SCALE = +-full scale */
    uint8_t flags;   /* FP_CMD_* */
} fp_command_t;

typedef struct {
    uint8_t reason;
} fp_stop_t;

typedef struct {
    uint32_t seq;
    uint32_t t_us; /* device time of the sample, microseconds, wraps */
    int16_t theta_adc;
    int16_t theta_dot_adc;
    int32_t phi_count;
    uint16_t status; /* FP_ST_* */
} fp_sample_t;

typedef struct {
    uint16_t flags; /* FP_ST_* */
    uint16_t rate_hz;
    uint16_t watchdog_ms;
    uint32_t crc_errors;
    uint32_t frame_errors;
    uint32_t frames_rx;
    uint32_t last_cmd_seq;
    uint32_t uart_overruns;    /* received bytes lost before the firmware read them */
    uint32_t uart_line_errors; /* bytes received with a framing, noise or parity error */
} fp_status_t;

typedef struct {
    uint8_t type; /* FP_MSG_*, selects the union member */
    union {
        fp_hello_t hello;
        fp_hello_ack_t hello_ack;
        fp_config_t config;
        fp_command_t command;
        fp_stop_t stop;
        fp_sample_t sample;
        fp_status_t status;
    } u;
} fp_msg_t;

/* ---- result codes (same numbering as Python's FrameStatus, negated) ------------------ */
#define FP_OK 0
#define FP_ERR_COBS (-1)         /* invalid COBS stuffing */
#define FP_ERR_CRC (-2)          /* CRC mismatch */
#define FP_ERR_LENGTH (-3)       /* shorter than type+CRC, or wrong size for its type */
#define FP_ERR_UNKNOWN_TYPE (-4) /* CRC-valid frame with an unknown type id */
#define FP_ERR_BUFFER (-5)       /* output buffer too small / frame too long */

/* ---- functions ------------------------------------------------------------------------- */

/* CRC-16/CCITT-FALSE (poly 0x1021, no reflection, no xorout); start with FP_CRC_INIT. */
uint16_t fp_crc16(const uint8_t *data, size_t len, uint16_t crc);

/* Body size of message type `type`, or 0 if the type is unknown. */
size_t fp_body_size(uint8_t type);

/* COBS-encode len bytes into out (no delimiter). Returns the encoded length, or 0 if
 * cap is too small (needs len + len/254 + 1). in and out must not overlap. */
size_t fp_cobs_encode(const uint8_t *in, size_t len, uint8_t *out, size_t cap);

/* COBS-decode one frame (no delimiter). Writes *out_len. out may equal in (in-place
 * decoding). Returns FP_OK, FP_ERR_COBS or FP_ERR_BUFFER. */
int fp_cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t cap, size_t *out_len);

/* Encode msg into a complete wire frame including the trailing 0x00. Returns its length
 * (at most FP_MAX_WIRE_LEN), or 0 if msg->type is unknown or cap is too small. */
size_t fp_encode(const fp_msg_t *msg, uint8_t *out, size_t cap);

/* Decode one frame given without its delimiter. Returns FP_OK and fills *msg, or a
 * negative FP_ERR_* code (then *msg is unspecified and must not be used). */
int fp_decode_frame(const uint8_t *frame, size_t len, fp_msg_t *msg);

/* ---- stream decoder: feed received bytes one at a time -------------------------------- */
typedef struct {
    uint8_t buf[FP_MAX_FRAME_LEN];
    size_t len;
    uint8_t skipping; /* discarding an over-long run up to the next delimiter */
    uint8_t lost;     /* a frame was rejected since the last good one */
    uint32_t frames_ok;
    uint32_t crc_errors;
    uint32_t length_errors;
    uint32_t unknown_type;
    uint32_t cobs_errors;
    uint32_t overlong;
    uint32_t resyncs; /* good frames that followed rejected ones */
    uint32_t bytes_discarded;
} fp_decoder_t;

void fp_decoder_init(fp_decoder_t *d);

/* Push one received byte. Returns 1 and fills *msg when it completes a valid frame,
 * 0 otherwise (rejected frames only update the counters). Never fails. */
int fp_decoder_push(fp_decoder_t *d, uint8_t byte, fp_msg_t *msg);

#ifdef __cplusplus
}
#endif

#endif /* FURUTA_PROTO_H */
