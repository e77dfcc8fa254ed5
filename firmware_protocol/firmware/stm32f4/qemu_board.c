/*
 * qemu_board.c - the firmware core on qemu-system-arm's netduinoplus2 (an STM32F405: the F401's USART2, TIM5
 * and NVIC at the same addresses; the tick is the SysTick, whose qemu model keeps its period under load) with the pendulum simulated in the image, so that `furuta-rt run --port`
 * can talk to the cross-compiled core over qemu's pseudo-terminal (tests/test_firmware_qemu.py).
 *
 * The plant is the rig's sampled linear model (eq. 6 with the actuator and the θ Bessel path, zero-order
 * hold at the tick), generated from furuta_rt's own model into qemu_plant.h by hil_mock/qemu.py: this file
 * only iterates x(k+1) = PHI x(k) + GAM u(k). qemu models no RCC and sends USART bytes synchronously, so
 * there is no clock set-up and TX is written straight to the data register. A test fixture, not a
 * board: it uses floating point (soft-float) for the plant, outside the core.
 */
#include <stdint.h>

#include "fw_core.h"
#include "qemu_plant.h"
#include "regs.h"
#include "ring.h"

struct fw_hal {
    ring_t rx;
    float x[PLANT_STATES]; /* θ, θ̇, φ, φ̇, θ_f, θ̇_f */
    float u;
};

static fw_hal_t hal;
static fw_t fw;
static const fw_board_t board = {
    0x51454D55u, PLANT_RATE_HZ, PLANT_RATE_HZ, 20u, PLANT_THETA_RAD_PER_COUNT, 0, PLANT_THETA_DOT_RAD_S_PER_COUNT, 0,
    PLANT_PHI_COUNTS_PER_REV, PLANT_FULL_SCALE, FP_ACT_TORQUE_NM, -32768, 32767, -32768, 32767,
    0u, 0u, /* CONFIG's limits: the protocol's (a host may ask for a slow rate and a long watchdog under qemu) */
};

void SysTick_Handler(void);
void USART2_IRQHandler(void);
int main(void);

static int32_t counts(float value, float per_count)
{
    float c = value / per_count;
    return (int32_t)(c >= 0.0f ? c + 0.5f : c - 0.5f);
}

static int16_t adc(float value, float per_count)
{
    int32_t c = counts(value, per_count);
    return (int16_t)(c > 32767 ? 32767 : (c < -32768 ? -32768 : c));
}

int32_t hal_encoder_count(fw_hal_t *h) { return counts(h->x[2], PLANT_PHI_RAD_PER_COUNT); }
uint8_t hal_encoder_fault(fw_hal_t *h) { (void)h; return 0u; }
int16_t hal_adc_theta(fw_hal_t *h) { return adc(h->x[4], PLANT_THETA_RAD_PER_COUNT); }
int16_t hal_adc_theta_dot(fw_hal_t *h) { return adc(h->x[5], PLANT_THETA_DOT_RAD_S_PER_COUNT); }
void hal_actuator_write(fw_hal_t *h, int16_t c) { h->u = (float)c * (PLANT_FULL_SCALE / 32767.0f); }
void hal_tick_rate(fw_hal_t *h, uint16_t rate_hz) { (void)h; SYST_RVR = QEMU_CPU_HZ / rate_hz - 1u; }

/* qemu starts the image afresh every time; its UART (a pseudo-terminal) has no line to err on. */
uint8_t hal_reset_cause(fw_hal_t *h) { (void)h; return FP_RESET_POWER_ON; }
void hal_uart_errors(fw_hal_t *h, uint32_t *overruns, uint32_t *line_errors)
{
    (void)h;
    *overruns = *line_errors = 0u;
}

/* A new host finds the pendulum put back near upright, as hil_mock does. */
void hal_session_started(fw_hal_t *h, uint8_t new_session)
{
    unsigned i;
    if (new_session) {
        for (i = 0; i < PLANT_STATES; i++) {
            h->x[i] = PLANT_X0[i];
        }
    }
}

uint8_t hal_uart_write(fw_hal_t *h, const uint8_t *data, size_t len)
{
    size_t i;
    (void)h;
    for (i = 0; i < len; i++) {
        while (!(USART2_SR & USART_SR_TXE)) {
        }
        USART2_DR = data[i];
    }
    return 1u;
}

static void plant_step(fw_hal_t *h)
{
    float next[PLANT_STATES];
    unsigned i, j;
    for (i = 0; i < PLANT_STATES; i++) {
        next[i] = PLANT_GAM[i] * h->u;
        for (j = 0; j < PLANT_STATES; j++) {
            next[i] += PLANT_PHI[i][j] * h->x[j];
        }
    }
    for (i = 0; i < PLANT_STATES; i++) {
        h->x[i] = next[i];
    }
}

/* Lockstep with the host: while streaming, a SysTick whose COMMAND answering the last SAMPLE has not arrived yet
 * is let pass (the core's time and the plant stand still, the CPU sleeps to the next SysTick), up to
 * LOCKSTEP_WAIT_TICKS in a row. qemu is not a real-time device and the host shares the machine: a slow host (a loaded
 * machine) then slows the device's time instead of leaving the pendulum under a stale command, so the closed loop
 * is the same at any load. A host that stopped answering gets the core's ordinary path (COMMAND_LATE, then the
 * watchdog in device time) after the wait. */
#define LOCKSTEP_WAIT_TICKS 100u

static unsigned waited;

void SysTick_Handler(void)
{
    int byte;
    while ((byte = ring_get(&hal.rx)) >= 0) {
        fw_rx_byte(&fw, (uint8_t)byte);
    }
    if (fw.streaming && fw.any_sent && !fw.answered && !fw.faults && waited < LOCKSTEP_WAIT_TICKS) {
        waited++;
        return;
    }
    waited = 0u;
    fw_tick(&fw);     /* latches the plant at tick k, sets the output for the coming period */
    plant_step(&hal); /* the plant to tick k + 1 under that output */
}

void USART2_IRQHandler(void)
{
    if (USART2_SR & USART_SR_RXNE) {
        (void)ring_put(&hal.rx, (uint8_t)USART2_DR);
    }
}

int main(void)
{
    hal_session_started(&hal, 1u);
    RCC_APB1ENR |= RCC_APB1ENR_USART2;
    USART2_CR1 = USART_CR1_UE | USART_CR1_TE | USART_CR1_RE | USART_CR1_RXNEIE;
    fw_init(&fw, &board, &hal);
    NVIC_IPR8(IRQ_USART2) = 0x40u; /* SysTick stays at the lowest priority: bytes pre-empt the tick */
    NVIC_ISER(IRQ_USART2 / 32u) = 1u << (IRQ_USART2 % 32u);
    SYST_CVR = 0u;
    SYST_CSR = 7u; /* CPU clock, interrupt, enable */
    for (;;) {
        __asm__ volatile("wfi");
    }
}
