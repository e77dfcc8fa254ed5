/*
 * host_hal.c - the firmware core built for the host (a shared library hil_mock loads with
 * ctypes, hil_mock/c_firmware.py). The HAL is fed by the caller: before each tick it passes the
 * sensor readings of hil_mock's plant and sensor models; after each call it reads the actuator
 * counts and the frames the core queued. No callbacks into Python, one device per host_device_t.
 */
#include <string.h>

#include "fw_core.h"

#define HOST_TX_BYTES 2048u
#define HOST_TX_FRAMES 64u

struct fw_hal {
    int16_t theta_adc, theta_dot_adc;
    int32_t phi_count;
    uint8_t encoder_fault;
    int16_t actuator;
    uint16_t tick_rate_hz;
    uint32_t sessions, new_sessions;
    uint8_t reset_cause;
    uint32_t uart_overruns, uart_line_errors;
    uint32_t tx_len, tx_frames;
    uint8_t tx[HOST_TX_BYTES];
    uint16_t tx_frame_len[HOST_TX_FRAMES];
};

typedef struct host_device {
    fw_t fw;
    fw_hal_t hal;
    fw_board_t board;
} host_device_t;

/* ---- the HAL ----------------------------------------------------------------------------------- */

int32_t hal_encoder_count(fw_hal_t *hal) { return hal->phi_count; }
uint8_t hal_encoder_fault(fw_hal_t *hal) { return hal->encoder_fault; }
int16_t hal_adc_theta(fw_hal_t *hal) { return hal->theta_adc; }
int16_t hal_adc_theta_dot(fw_hal_t *hal) { return hal->theta_dot_adc; }
void hal_actuator_write(fw_hal_t *hal, int16_t counts) { hal->actuator = counts; }
void hal_tick_rate(fw_hal_t *hal, uint16_t rate_hz) { hal->tick_rate_hz = rate_hz; }

void hal_session_started(fw_hal_t *hal, uint8_t new_session)
{
    hal->sessions++;
    if (new_session) {
        hal->new_sessions++;
    }
}

uint8_t hal_reset_cause(fw_hal_t *hal) { return hal->reset_cause; }

void hal_uart_errors(fw_hal_t *hal, uint32_t *overruns, uint32_t *line_errors)
{
    *overruns = hal->uart_overruns;
    *line_errors = hal->uart_line_errors;
}

uint8_t hal_uart_write(fw_hal_t *hal, const uint8_t *data, size_t len)
{
    if (hal->tx_frames >= HOST_TX_FRAMES || len > HOST_TX_BYTES - hal->tx_len) {
        return 0u;
    }
    memcpy(hal->tx + hal->tx_len, data, len);
    hal->tx_len += (uint32_t)len;
    hal->tx_frame_len[hal->tx_frames++] = (uint16_t)len;
    return 1u;
}

/* ---- the library's interface (hil_mock/c_firmware.py declares the same signatures) ------------- */

size_t host_device_size(void);
void host_device_init(host_device_t *dev, const fw_board_t *board);
void host_rx(host_device_t *dev, const uint8_t *data, size_t len);
void host_tick(host_device_t *dev, int16_t theta_adc, int16_t theta_dot_adc, int32_t phi_count, uint8_t encoder_fault);
void host_skip(host_device_t *dev, uint32_t periods);
void host_reboot(host_device_t *dev, uint8_t reset_cause);
void host_uart_errors(host_device_t *dev, uint32_t overruns, uint32_t line_errors);
void host_hangup(host_device_t *dev);
void host_note_tx_overflow(host_device_t *dev);
uint32_t host_take_tx(host_device_t *dev, uint8_t *out, uint16_t *frame_len);
void host_state(const host_device_t *dev, uint64_t *out);
uint8_t host_command_accepted(uint32_t seq, uint8_t any_sent, uint32_t last_sent, uint8_t any_accepted,
                              uint32_t last_accepted);
size_t host_board_size(void);
const fw_t *host_core(const host_device_t *dev);
uint32_t host_new_sessions(const host_device_t *dev);
uint32_t host_tx_pending(const host_device_t *dev);

size_t host_device_size(void) { return sizeof(host_device_t); }
size_t host_board_size(void) { return sizeof(fw_board_t); }

void host_device_init(host_device_t *dev, const fw_board_t *board)
{
    memset(dev, 0, sizeof *dev);
    dev->board = *board;
    dev->hal.reset_cause = FP_RESET_POWER_ON;
    fw_init(&dev->fw, &dev->board, &dev->hal);
}

void host_rx(host_device_t *dev, const uint8_t *data, size_t len)
{
    size_t i;
    for (i = 0; i < len; i++) {
        fw_rx_byte(&dev->fw, data[i]);
    }
}

void host_tick(host_device_t *dev, int16_t theta_adc, int16_t theta_dot_adc, int32_t phi_count, uint8_t encoder_fault)
{
    dev->hal.theta_adc = theta_adc;
    dev->hal.theta_dot_adc = theta_dot_adc;
    dev->hal.phi_count = phi_count;
    dev->hal.encoder_fault = encoder_fault;
    fw_tick(&dev->fw);
}

void host_skip(host_device_t *dev, uint32_t periods) { fw_skip(&dev->fw, periods); }

/* A device reset for `reset_cause` (FP_RESET_*); the UART's error counters restart with it. */
void host_reboot(host_device_t *dev, uint8_t reset_cause)
{
    dev->hal.tx_len = dev->hal.tx_frames = 0u; /* frames not yet written are lost with the reset */
    dev->hal.reset_cause = reset_cause;
    dev->hal.uart_overruns = dev->hal.uart_line_errors = 0u;
    fw_reboot(&dev->fw);
}

/* The receiver's error counts since start-up, as a UART would count them (hil_mock simulates a line). */
void host_uart_errors(host_device_t *dev, uint32_t overruns, uint32_t line_errors)
{
    dev->hal.uart_overruns = overruns;
    dev->hal.uart_line_errors = line_errors;
}

void host_hangup(host_device_t *dev) { fw_hangup(&dev->fw); }
void host_note_tx_overflow(host_device_t *dev) { fw_note_tx_overflow(&dev->fw); }

/* Copy the queued frames to out (>= HOST_TX_BYTES) and their lengths to frame_len
 * (>= HOST_TX_FRAMES); returns the number of frames and empties the queue. */
uint32_t host_take_tx(host_device_t *dev, uint8_t *out, uint16_t *frame_len)
{
    uint32_t n = dev->hal.tx_frames;
    memcpy(out, dev->hal.tx, dev->hal.tx_len);
    memcpy(frame_len, dev->hal.tx_frame_len, n * sizeof *frame_len);
    dev->hal.tx_len = dev->hal.tx_frames = 0u;
    return n;
}

/* The state hil_mock reads after every call, in the order of c_firmware.STATE_FIELDS. */
void host_state(const host_device_t *dev, uint64_t *out)
{
    const fw_t *fw = &dev->fw;
    const fp_decoder_t *d = &fw->dec;
    out[0] = fw->clock_ns;
    out[1] = fw->period_ns;
    out[2] = fw->rate_hz;
    out[3] = fw->watchdog_ms;
    out[4] = fw->streaming;
    out[5] = fw->enabled;
    out[6] = fw->answered;
    out[7] = fw->any_applied;
    out[8] = (uint16_t)fw->output;
    out[9] = fw->faults;
    out[10] = fw_status_flags(fw);
    out[11] = dev->hal.new_sessions;
    out[12] = dev->hal.tx_frames;
    out[13] = fw->n.commands_rx;
    out[14] = fw->n.commands_applied;
    out[15] = fw->n.commands_discarded;
    out[16] = fw->n.watchdog_trips;
    out[17] = fw->n.handshakes;
    out[18] = fw->n.handshakes_refused;
    out[19] = fw->n.samples_sent;
    out[20] = fw->n.status_sent;
    out[21] = fw->n.hangups;
    out[22] = fw->n.reboots;
    out[23] = d->frames_ok;
    out[24] = d->crc_errors;
    out[25] = d->crc_errors + d->length_errors + d->unknown_type + d->cobs_errors + d->overlong;
    out[26] = fw->seq;
    out[27] = fw->last_cmd_seq;
    out[28] = fw->n.commands_other_session;
}

uint8_t host_command_accepted(uint32_t seq, uint8_t any_sent, uint32_t last_sent, uint8_t any_accepted,
                              uint32_t last_accepted)
{
    return fw_command_accepted(seq, any_sent, last_sent, any_accepted, last_accepted);
}

/* For a device built on top of this one (hil_mock/csrc/device.c): the core's state, HELLOs that started a new
 * session, frames queued. */
const fw_t *host_core(const host_device_t *dev) { return &dev->fw; }
uint32_t host_new_sessions(const host_device_t *dev) { return dev->hal.new_sessions; }
uint32_t host_tx_pending(const host_device_t *dev) { return dev->hal.tx_frames; }
