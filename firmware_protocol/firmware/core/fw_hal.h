/*
 * fw_hal.h - the hardware-abstraction layer the firmware core (fw_core.c) calls.
 *
 * Each target defines `struct fw_hal` (its private state: registers, buffers) and the
 * functions below: host/host_hal.c (the hil_mock plant behind it), stm32f4/board.c (registers).
 * The two other HAL duties are calls *into* the core: the target's periodic timer interrupt
 * calls fw_tick() at the configured rate, and the bytes its UART received are passed to
 * fw_rx_byte() (on the board: drained from the RX ring at the start of each tick, so that
 * nothing else touches the core's state).
 *
 * All HAL functions are called from the tick context. None may block. No floating point.
 */
#ifndef FW_HAL_H
#define FW_HAL_H

#include <stddef.h>
#include <stdint.h>

typedef struct fw_hal fw_hal_t; /* defined by the target */

/* Arm encoder count (quadrature, x4, signed, wraps modulo 2^32). */
int32_t hal_encoder_count(fw_hal_t *hal);
/* Nonzero while the encoder reports an error (illegal transition, signal loss); 0 if the
 * target cannot detect one. Latches ENCODER_ERROR. */
uint8_t hal_encoder_fault(fw_hal_t *hal);
/* Pendulum angle and rate ADC channels, latched at this tick, in the counts HELLO_ACK's
 * calibration refers to. */
int16_t hal_adc_theta(fw_hal_t *hal);
int16_t hal_adc_theta_dot(fw_hal_t *hal);
/* Actuator command, +-32767 = +-actuator_full_scale, 0 = no drive. Called on every change. */
void hal_actuator_write(fw_hal_t *hal, int16_t counts);
/* Queue one whole frame for the UART. Returns 1 when queued, 0 when it did not fit
 * (nothing queued; the core reports TX_OVERFLOW). */
uint8_t hal_uart_write(fw_hal_t *hal, const uint8_t *data, size_t len);
/* Reprogram the periodic tick to rate_hz (a CONFIG was applied). */
void hal_tick_rate(fw_hal_t *hal, uint16_t rate_hz);
/* A HELLO was accepted; new_session: the device was idle before (a new host). */
void hal_session_started(fw_hal_t *hal, uint8_t new_session);
/* What started this firmware (FP_RESET_*), for HELLO_ACK: constant from start-up. */
uint8_t hal_reset_cause(fw_hal_t *hal);
/* The receiver's error counts since start-up, free-running (they wrap): bytes lost before the firmware read them
 * (the UART's overrun, a full receive buffer) and bytes received with a framing, noise or parity error. */
void hal_uart_errors(fw_hal_t *hal, uint32_t *overruns, uint32_t *line_errors);

#endif /* FW_HAL_H */
