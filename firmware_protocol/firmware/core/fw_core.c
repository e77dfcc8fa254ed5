/*
 * fw_core.c - the DAQ firmware core. See fw_core.h; the rules are PROTOCOL.md §4-7, and where
 * the spec leaves a choice this follows hil_mock/firmware.py (its module docstring lists them).
 */
#include "fw_core.h"

#include <string.h> /* memcpy, memset */

#define NS_PER_MS 1000000u

/* ---- §6 command acceptance ---------------------------------------------------------------- */

/* new - old of wrapping 32-bit counters is positive: in (0, 2^31] (messages.wrap_delta). */
static uint8_t newer(uint32_t new_value, uint32_t old_value)
{
    uint32_t d = new_value - old_value;
    return (uint8_t)(d != 0u && d <= 0x80000000u);
}

uint8_t fw_command_accepted(uint32_t seq, uint8_t any_sent, uint32_t last_sent, uint8_t any_accepted,
                            uint32_t last_accepted)
{
    if (!any_sent || newer(seq, last_sent)) {
        return 0u; /* nothing to answer yet, or answers a SAMPLE not sent */
    }
    return (uint8_t)(!any_accepted || newer(seq, last_accepted));
}

/* ---- helpers --------------------------------------------------------------------------------- */

static void set_output(fw_t *fw, int16_t counts)
{
    if (counts != fw->output) {
        fw->output = counts;
        hal_actuator_write(fw->hal, counts);
    }
}

static uint32_t decoder_errors(const fp_decoder_t *d)
{
    return d->crc_errors + d->length_errors + d->unknown_type + d->cobs_errors + d->overlong;
}

static void decoder_flush(fp_decoder_t *d)
{
    d->len = 0u; /* counters are kept */
    d->skipping = 0u;
}

/* round(1e9 / rate_hz), ties to even as Python's round() (hil_mock/firmware.py). */
static uint32_t period_ns_of(uint16_t rate_hz)
{
    uint32_t q = 1000000000u / rate_hz;
    uint32_t twice_rem = 2u * (1000000000u % rate_hz);
    if (twice_rem > rate_hz || (twice_rem == rate_hz && (q & 1u))) {
        q++;
    }
    return q;
}

static void set_rate(fw_t *fw, uint16_t rate_hz)
{
    uint8_t changed = (uint8_t)(rate_hz != fw->rate_hz);
    fw->rate_hz = rate_hz;
    fw->period_ns = period_ns_of(rate_hz);
    fw->period_us = fw->period_ns / 1000u;
    fw->period_ns_rem = fw->period_ns % 1000u;
    if (changed) {
        hal_tick_rate(fw->hal, rate_hz);
    }
}

static void set_watchdog(fw_t *fw, uint16_t watchdog_ms)
{
    fw->watchdog_ms = watchdog_ms;
    fw->watchdog_ns = (uint64_t)watchdog_ms * NS_PER_MS;
}

static void send(fw_t *fw, const uint8_t *frame, size_t len)
{
    if (len == 0u || !hal_uart_write(fw->hal, frame, len)) {
        fw->sticky |= FP_ST_TX_OVERFLOW;
        fw->n.tx_dropped++;
    }
}

static void send_msg(fw_t *fw, const fp_msg_t *msg)
{
    uint8_t buf[FP_MAX_WIRE_LEN];
    send(fw, buf, fp_encode(msg, buf, sizeof buf));
}

uint16_t fw_status_flags(const fw_t *fw)
{
    uint16_t flags = (uint16_t)(fw->faults | fw->sticky);
    if (fw->enabled) {
        flags |= FP_ST_ENABLED;
    }
    if (fw->config_rejected) {
        flags |= FP_ST_CONFIG_REJECTED;
    }
    return flags;
}

static void send_status(fw_t *fw)
{
    fp_msg_t m;
    const fp_decoder_t *d = &fw->dec;
    uint32_t overruns, line_errors;
    hal_uart_errors(fw->hal, &overruns, &line_errors);
    m.type = FP_MSG_STATUS;
    m.u.status.flags = fw_status_flags(fw);
    m.u.status.rate_hz = fw->rate_hz;
    m.u.status.watchdog_ms = fw->watchdog_ms;
    m.u.status.crc_errors = d->crc_errors - fw->base_crc;
    m.u.status.frame_errors = decoder_errors(d) - d->crc_errors - fw->base_other;
    m.u.status.frames_rx = d->frames_ok - fw->base_ok;
    m.u.status.last_cmd_seq = fw->last_cmd_seq;
    m.u.status.uart_overruns = overruns - fw->base_uart_overruns;
    m.u.status.uart_line_errors = line_errors - fw->base_uart_line_errors;
    send_msg(fw, &m);
    fw->n.status_sent++;
}

/* ---- states ---------------------------------------------------------------------------------- */

static void go_idle(fw_t *fw)
{
    fw->streaming = 0u;
    fw->enabled = 0u;
    fw->held.valid = 0u;
    fw->fresh.valid = 0u;
    fw->any_applied = 0u;
    fw->answered = 0u;
    fw->last_cmd_seq = 0u;
    set_output(fw, 0);
}

static void boot(fw_t *fw)
{
    const fw_board_t *b = fw->board;
    set_rate(fw, b->default_rate_hz);
    set_watchdog(fw, b->default_watchdog_ms);
    fw->faults = 0u;
    fw->sticky = 0u;
    fw->config_rejected = 0u;
    fw->seq = 0u;
    fw->any_sent = 0u;
    fw->rx_errors_seen = decoder_errors(&fw->dec);
    fw->base_crc = fw->base_other = fw->base_ok = 0u;
    hal_uart_errors(fw->hal, &fw->base_uart_overruns, &fw->base_uart_line_errors);
    fw->last_cmd_ns = 0u;
    fw->next_status_ns = 0u;
    go_idle(fw);
}

void fw_init(fw_t *fw, const fw_board_t *board, fw_hal_t *hal)
{
    memset(fw, 0, sizeof *fw);
    fw->board = board;
    fw->hal = hal;
    fp_decoder_init(&fw->dec);
    hal_actuator_write(hal, 0); /* safe state before anything else */
    hal_tick_rate(hal, board->default_rate_hz);
    fw->rate_hz = board->default_rate_hz;
    boot(fw);
}

void fw_reboot(fw_t *fw)
{
    decoder_flush(&fw->dec);
    fw->n.reboots++;
    boot(fw);
}

void fw_hangup(fw_t *fw)
{
    if (fw->streaming) {
        fw->n.hangups++;
    }
    go_idle(fw);
    decoder_flush(&fw->dec);
}

void fw_note_tx_overflow(fw_t *fw) { fw->sticky |= FP_ST_TX_OVERFLOW; }

/* ---- received messages ----------------------------------------------------------------------- */

static void on_hello(fw_t *fw, const fp_hello_t *h)
{
    const fw_board_t *b = fw->board;
    const fp_decoder_t *d = &fw->dec;
    uint8_t buf[FP_MAX_WIRE_LEN + 1u];
    fp_msg_t m;
    uint8_t was_streaming = fw->streaming;

    m.type = FP_MSG_HELLO_ACK; /* always the device's own identity */
    m.u.hello_ack.protocol_version = FP_PROTOCOL_VERSION;
    m.u.hello_ack.schema_hash = FP_SCHEMA_HASH;
    m.u.hello_ack.nonce = h->nonce;
    m.u.hello_ack.device_id = b->device_id;
    m.u.hello_ack.fw_major = FW_VERSION_MAJOR;
    m.u.hello_ack.fw_minor = FW_VERSION_MINOR;
    m.u.hello_ack.fw_patch = FW_VERSION_PATCH;
    m.u.hello_ack.sample_rate_hz = fw->rate_hz;
    m.u.hello_ack.watchdog_ms = fw->watchdog_ms;
    m.u.hello_ack.theta_rad_per_count = b->theta_rad_per_count;
    m.u.hello_ack.theta_offset_counts = b->theta_offset_counts;
    m.u.hello_ack.theta_dot_rad_s_per_count = b->theta_dot_rad_s_per_count;
    m.u.hello_ack.theta_dot_offset_counts = b->theta_dot_offset_counts;
    m.u.hello_ack.phi_counts_per_rev = b->phi_counts_per_rev;
    m.u.hello_ack.actuator_full_scale = b->actuator_full_scale;
    m.u.hello_ack.actuator_kind = b->actuator_kind;
    m.u.hello_ack.reset_cause = hal_reset_cause(fw->hal);
    buf[0] = 0u; /* §2.1: flush the peer's partial frame */
    send(fw, buf, 1u + fp_encode(&m, buf + 1, sizeof buf - 1u));

    if (h->protocol_version != FP_PROTOCOL_VERSION || h->schema_hash != FP_SCHEMA_HASH) {
        fw->n.handshakes_refused++;
        go_idle(fw); /* never stream or drive for a host built against other definitions */
        return;
    }
    fw->n.handshakes++;
    hal_session_started(fw->hal, (uint8_t)!was_streaming);
    go_idle(fw); /* restart the session: output zero, faults kept */
    fw->streaming = 1u;
    fw->session = h->nonce; /* from now on a COMMAND of an earlier session is discarded */
    fw->seq = 0u;
    fw->any_sent = 0u;
    fw->sticky = 0u;
    fw->last_cmd_ns = fw->clock_ns; /* watchdog armed by the handshake (§5) */
    fw->next_status_ns = fw->clock_ns + FW_STATUS_PERIOD_NS;
    fw->base_crc = d->crc_errors;
    fw->base_other = decoder_errors(d) - d->crc_errors;
    fw->base_ok = d->frames_ok; /* the HELLO itself is not counted */
    fw->rx_errors_seen = decoder_errors(d);
    hal_uart_errors(fw->hal, &fw->base_uart_overruns, &fw->base_uart_line_errors);
}

static void on_config(fw_t *fw, const fp_config_t *c)
{
    const fw_board_t *b = fw->board;
    if (c->rate_hz >= 1u && c->rate_hz >= b->min_rate_hz && c->rate_hz <= b->max_rate_hz && c->watchdog_ms >= 1u &&
        (b->max_watchdog_ms == 0u || c->watchdog_ms <= b->max_watchdog_ms)) {
        fw->config_rejected = 0u;
        set_rate(fw, c->rate_hz);
        set_watchdog(fw, c->watchdog_ms);
        fw->held.valid = 0u;
        fw->fresh.valid = 0u;
        fw->enabled = 0u;
        set_output(fw, 0);
    } else {
        fw->config_rejected = 1u;
    }
    send_status(fw);
}

static void on_command(fw_t *fw, const fp_command_t *c)
{
    uint32_t last_sent = fw->seq - 1u;
    uint8_t any_ref = (uint8_t)(fw->fresh.valid || fw->any_applied);
    uint32_t ref = fw->fresh.valid ? fw->fresh.seq : fw->last_applied;

    fw->n.commands_rx++;
    if (fw->streaming && c->session != fw->session) {
        fw->n.commands_discarded++; /* another session's (delayed, or a second host's): never applied */
        fw->n.commands_other_session++;
        return;
    }
    if (!fw->streaming || !fw_command_accepted(c->seq, fw->any_sent, last_sent, any_ref, ref)) {
        fw->n.commands_discarded++; /* stale: not applied, does not feed the watchdog */
        return;
    }
    fw->fresh.seq = c->seq;
    fw->fresh.counts = c->command;
    fw->fresh.flags = c->flags;
    fw->fresh.valid = 1u;
    if (c->seq == last_sent) {
        fw->answered = 1u;
    }
}

void fw_rx_byte(fw_t *fw, uint8_t byte)
{
    fp_msg_t m;
    if (!fp_decoder_push(&fw->dec, byte, &m)) {
        return;
    }
    switch (m.type) {
    case FP_MSG_COMMAND: on_command(fw, &m.u.command); break;
    case FP_MSG_HELLO: on_hello(fw, &m.u.hello); break;
    case FP_MSG_CONFIG: on_config(fw, &m.u.config); break;
    case FP_MSG_STOP: go_idle(fw); break;
    default: break; /* device -> host types (a loopback, a confused host) are ignored */
    }
}

/* ---- time ------------------------------------------------------------------------------------ */

static void advance_clock(fw_t *fw)
{
    fw->clock_ns += fw->period_ns;
    fw->clock_us += fw->period_us;
    fw->clock_ns_rem += fw->period_ns_rem;
    if (fw->clock_ns_rem >= 1000u) {
        fw->clock_ns_rem -= 1000u;
        fw->clock_us++;
    }
}

void fw_skip(fw_t *fw, uint32_t periods)
{
    if (periods == 0u) {
        return;
    }
    fw->clock_ns += (uint64_t)periods * fw->period_ns; /* overrun path only: 64-bit divide allowed */
    fw->clock_us = (uint32_t)(fw->clock_ns / 1000u);
    fw->clock_ns_rem = (uint32_t)(fw->clock_ns % 1000u);
    fw->sticky |= FP_ST_TICK_OVERRUN;
}

static uint8_t at_rail(int32_t v, int32_t lo, int32_t hi) { return (uint8_t)(v <= lo || v >= hi); }

static void latch_fault(fw_t *fw, uint16_t bit)
{
    fw->faults |= bit;
    send_status(fw);
}

static void streaming_tick(fw_t *fw)
{
    const fw_board_t *b = fw->board;
    uint64_t now = fw->clock_ns;
    uint8_t clearing = 0u;
    uint16_t late;
    fp_msg_t m;
    /* 1. acquisition */
    int16_t theta = hal_adc_theta(fw->hal);
    int16_t theta_dot = hal_adc_theta_dot(fw->hal);
    int32_t phi = hal_encoder_count(fw->hal);
    uint8_t enc_fault = hal_encoder_fault(fw->hal);
    uint8_t over = (uint8_t)(at_rail(theta, b->theta_adc_min, b->theta_adc_max) ||
                             at_rail(theta_dot, b->theta_dot_adc_min, b->theta_dot_adc_max));

    /* 2. the newest accepted COMMAND */
    if (fw->fresh.valid) {
        fw->held = fw->fresh;
        fw->fresh.valid = 0u;
        fw->last_applied = fw->held.seq;
        fw->any_applied = 1u;
        fw->last_cmd_seq = fw->held.seq;
        fw->last_cmd_ns = now;
        fw->n.commands_applied++;
        if (fw->held.flags & FP_CMD_CLEAR_FAULT) {
            uint16_t keep = (uint16_t)((over ? FP_ST_ADC_OVERRANGE : 0u) | (enc_fault ? FP_ST_ENCODER_ERROR : 0u));
            uint16_t cleared = (uint16_t)(fw->faults & ~keep);
            clearing = 1u;
            if (cleared) {
                fw->faults &= (uint16_t)~cleared;
                send_status(fw);
            }
            fw->held.counts = 0; /* output zero now; ENABLE takes effect from the next COMMAND */
            fw->held.flags = 0u;
        }
    }
    late = (fw->any_sent && !fw->answered) ? FP_ST_COMMAND_LATE : 0u;
    fw->answered = 0u;

    /* 3. faults */
    if (!(fw->faults & FP_ST_WATCHDOG_TRIPPED) && now - fw->last_cmd_ns >= fw->watchdog_ns) {
        fw->n.watchdog_trips++;
        latch_fault(fw, FP_ST_WATCHDOG_TRIPPED);
    }
    if (over && !(fw->faults & FP_ST_ADC_OVERRANGE)) {
        latch_fault(fw, FP_ST_ADC_OVERRANGE);
    }
    if (enc_fault && !(fw->faults & FP_ST_ENCODER_ERROR)) {
        latch_fault(fw, FP_ST_ENCODER_ERROR);
    }
    fw->enabled = (uint8_t)(fw->held.valid && (fw->held.flags & FP_CMD_ENABLE) && !fw->faults && !clearing);

    /* 4. SAMPLE k */
    m.type = FP_MSG_SAMPLE;
    m.u.sample.seq = fw->seq;
    m.u.sample.t_us = fw->clock_us;
    m.u.sample.theta_adc = theta;
    m.u.sample.theta_dot_adc = theta_dot;
    m.u.sample.phi_count = phi;
    m.u.sample.status = (uint16_t)(fw_status_flags(fw) | late);
    send_msg(fw, &m);
    fw->sticky = 0u;
    fw->seq++;
    fw->any_sent = 1u;
    fw->n.samples_sent++;
    if (now >= fw->next_status_ns) {
        fw->next_status_ns = now + FW_STATUS_PERIOD_NS;
        send_status(fw);
    }

    /* 5. output for the coming period (§4: -32768 acts as -32767) */
    if (fw->enabled) {
        set_output(fw, fw->held.counts < -FP_COMMAND_FULL_SCALE ? (int16_t)-FP_COMMAND_FULL_SCALE : fw->held.counts);
    } else {
        set_output(fw, 0);
    }
}

void fw_tick(fw_t *fw)
{
    uint32_t errors = decoder_errors(&fw->dec);
    if (errors != fw->rx_errors_seen) {
        fw->rx_errors_seen = errors;
        fw->sticky |= FP_ST_CRC_ERROR;
    }
    if (fw->streaming) {
        streaming_tick(fw);
    }
    advance_clock(fw);
}
