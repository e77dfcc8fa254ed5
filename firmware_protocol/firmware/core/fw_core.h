/*
 * fw_core.h - the portable DAQ firmware core (C99): protocol session, device-timed sampling,
 * command acceptance, watchdog and fault flags of firmware_protocol/PROTOCOL.md §4-7.
 *
 * No dynamic memory, no floating-point arithmetic (the calibration floats are only copied
 * into HELLO_ACK), no libc beyond memcpy/memset. All state is in one fw_t; a target owns one
 * (static) and calls, from one context only (its timer interrupt):
 *
 *     fw_rx_byte(fw, b)   for each byte its UART received since the previous tick, then
 *     fw_tick(fw)         once per period of the tick timer
 *
 * and, outside the tick if at all, fw_skip (the timer fired without the tick running),
 * fw_hangup (DTR drop on USB CDC) and fw_note_tx_overflow. The hardware is reached through
 * fw_hal.h. hil_mock's Python device (hil_mock/firmware.py) implements the same rules; the
 * conformance tests (tests/test_firmware_c.py) check that both send byte-identical traces.
 */
#ifndef FW_CORE_H
#define FW_CORE_H

#include <stdint.h>

#include "furuta_proto.h"
#include "fw_hal.h"

#define FW_VERSION_MAJOR 0u
#define FW_VERSION_MINOR 3u
#define FW_VERSION_PATCH 0u
#define FW_STATUS_PERIOD_NS 1000000000u /* STATUS at least once per second while streaming */

/* What the board is: identity, limits and the calibration reported in HELLO_ACK. Constant. */
typedef struct {
    uint32_t device_id;
    uint16_t default_rate_hz;
    uint16_t max_rate_hz; /* CONFIG accepts max(1, min_rate_hz)..max_rate_hz */
    uint16_t default_watchdog_ms;
    float theta_rad_per_count;
    int16_t theta_offset_counts;
    float theta_dot_rad_s_per_count;
    int16_t theta_dot_offset_counts;
    uint32_t phi_counts_per_rev;
    float actuator_full_scale;
    uint8_t actuator_kind; /* FP_ACT_* */
    /* ADC rails: a reading at or beyond one is over-range (ADC_OVERRANGE); rails outside the int16
     * range: never (a full-turn θ sensor that wraps instead of saturating) */
    int32_t theta_adc_min, theta_adc_max;
    int32_t theta_dot_adc_min, theta_dot_adc_max;
    /* limits of the hardware on CONFIG (0: none): the slowest tick that still refreshes the board's hardware
     * watchdog, and the longest a COMMAND may be held without host traffic (watchdog_ms 1..max_watchdog_ms) */
    uint16_t min_rate_hz;
    uint16_t max_watchdog_ms;
} fw_board_t;

/* A COMMAND kept for application: the SAMPLE seq it answers, its counts and flags. */
typedef struct {
    uint32_t seq;
    int16_t counts;
    uint8_t flags;
    uint8_t valid;
} fw_cmd_t;

/* Counters for diagnostics (never reset by the protocol, only by fw_init). */
typedef struct {
    uint32_t commands_rx, commands_applied, commands_discarded, commands_other_session;
    uint32_t watchdog_trips, handshakes, handshakes_refused;
    uint32_t samples_sent, status_sent, hangups, reboots, tx_dropped;
} fw_counters_t;

typedef struct {
    const fw_board_t *board;
    fw_hal_t *hal;
    fp_decoder_t dec;
    /* device clock since init; runs on through fw_reboot (a free-running timer) */
    uint64_t clock_ns;
    uint32_t clock_us, clock_ns_rem; /* clock_ns / 1000 and % 1000 without a 64-bit divide */
    uint32_t period_ns, period_us, period_ns_rem;
    uint16_t rate_hz, watchdog_ms;
    uint64_t watchdog_ns;
    uint16_t faults;  /* latched FP_ST_FAULT_MASK bits */
    uint16_t sticky;  /* CRC_ERROR | TICK_OVERRUN | TX_OVERFLOW since the previous SAMPLE */
    uint8_t config_rejected;
    uint8_t streaming, enabled, answered;
    uint32_t session;  /* nonce of the HELLO that started the session: every COMMAND must carry it */
    uint8_t any_sent;  /* a SAMPLE was sent in this session */
    uint32_t seq;      /* seq of the next SAMPLE */
    fw_cmd_t held;     /* the applied COMMAND being held */
    fw_cmd_t fresh;    /* newest accepted COMMAND not yet applied */
    uint8_t any_applied;
    uint32_t last_applied, last_cmd_seq;
    uint64_t last_cmd_ns, next_status_ns;
    uint32_t rx_errors_seen;
    uint32_t base_crc, base_other, base_ok; /* decoder counters at the last HELLO */
    uint32_t base_uart_overruns, base_uart_line_errors; /* the HAL's UART counters at the last HELLO */
    int16_t output;                         /* last value written to the actuator */
    fw_counters_t n;
} fw_t;

/* Power-up: default configuration, idle, output zero, no fault, clock 0. */
void fw_init(fw_t *fw, const fw_board_t *board, fw_hal_t *hal);
/* Device reset: power-up state except the clock, which runs on. */
void fw_reboot(fw_t *fw);
/* One received byte; complete frames act at once (a COMMAND is applied at the next tick). */
void fw_rx_byte(fw_t *fw, uint8_t byte);
/* One timer period: latch sensors, apply the newest COMMAND, faults, SAMPLE, output. */
void fw_tick(fw_t *fw);
/* The timer fired `periods` times without fw_tick: clock moves on, TICK_OVERRUN, seq kept. */
void fw_skip(fw_t *fw, uint32_t periods);
/* The host closed the port (DTR drop): output zero, idle; latched faults are kept. */
void fw_hangup(fw_t *fw);
/* The transport dropped an outgoing frame: TX_OVERFLOW in the next SAMPLE. */
void fw_note_tx_overflow(fw_t *fw);
/* §6 acceptance (firmware_protocol/acceptance.py command_accepted): a COMMAND answering SAMPLE
 * `seq` is accepted iff a SAMPLE was sent, seq is not newer than the last one sent, and seq is
 * newer than the last accepted COMMAND (if any), modulo 2^32. */
uint8_t fw_command_accepted(uint32_t seq, uint8_t any_sent, uint32_t last_sent, uint8_t any_accepted,
                            uint32_t last_accepted);
/* StatusFlags as reported now (faults, sticky, ENABLED, CONFIG_REJECTED). */
uint16_t fw_status_flags(const fw_t *fw);

#endif /* FW_CORE_H */
