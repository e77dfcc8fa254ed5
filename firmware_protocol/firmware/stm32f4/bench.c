/*
 * bench.c - the worst ticks of the firmware core, for counting their instructions under
 * qemu-system-arm (scripts/build_firmware). The same core and codec as the board image (frames queued into a
 * byte ring where the board copies them for its DMA: a little dearer than the board),
 * with a HAL of plain variables: sensors at the rails, 100 received bytes per tick (1 Mbaud at
 * 1 kHz), faults latching. bench_mark() brackets each measured tick; the script counts the
 * instructions qemu executes between two marks. It also paints the free stack before the ticks and prints
 * the deepest use after them ("stack_bytes N", semihosting). Ends with a semihosting exit.
 */
#include <stdint.h>
#include <string.h>

#include "board_config.h"
#include "fw_core.h"
#include "ring.h"

#define RX_PER_TICK 100u /* bytes in one 1 ms tick at 1 Mbaud (10 bits per byte) */

struct fw_hal {
    ring_t tx;
    int16_t theta, theta_dot;
    int32_t phi;
    uint8_t encoder_fault;
    int16_t actuator;
};

static fw_hal_t hal;
static fw_t fw;
static const fw_board_t board = {
    0x42454E43u, 1000u, BOARD_MAX_RATE_HZ, BOARD_WATCHDOG_MS, BOARD_THETA_RAD_PER_COUNT, 0,
    BOARD_THETA_DOT_RAD_S_PER_COUNT, 0, BOARD_PHI_COUNTS_PER_REV, BOARD_ACTUATOR_FULL_SCALE, BOARD_ACTUATOR_KIND,
    BOARD_ADC_MIN, BOARD_ADC_MAX, BOARD_ADC_MIN, BOARD_ADC_MAX, BOARD_MIN_RATE_HZ, BOARD_MAX_WATCHDOG_MS,
};

void bench_mark(uint32_t tick);
int main(void);

int32_t hal_encoder_count(fw_hal_t *h) { return h->phi; }
uint8_t hal_encoder_fault(fw_hal_t *h) { return h->encoder_fault; }
int16_t hal_adc_theta(fw_hal_t *h) { return h->theta; }
int16_t hal_adc_theta_dot(fw_hal_t *h) { return h->theta_dot; }
void hal_actuator_write(fw_hal_t *h, int16_t counts) { h->actuator = counts; }
void hal_tick_rate(fw_hal_t *h, uint16_t rate_hz) { (void)h; (void)rate_hz; }
void hal_session_started(fw_hal_t *h, uint8_t new_session) { (void)h; (void)new_session; }
uint8_t hal_reset_cause(fw_hal_t *h) { (void)h; return FP_RESET_POWER_ON; }
void hal_uart_errors(fw_hal_t *h, uint32_t *overruns, uint32_t *line_errors)
{
    (void)h;
    *overruns = *line_errors = 0u;
}

uint8_t hal_uart_write(fw_hal_t *h, const uint8_t *data, size_t len) { return ring_put_all(&h->tx, data, len); }

__attribute__((noinline)) void bench_mark(uint32_t tick) { __asm__ volatile("" : : "r"(tick) : "memory"); }

static uint8_t rx[RX_PER_TICK];
static size_t rx_len;

static void queue(const fp_msg_t *m)
{
    size_t n = fp_encode(m, rx + rx_len, sizeof rx - rx_len);
    rx_len += n;
}

#define SESSION 7u /* the HELLO's nonce, carried by every COMMAND */

static void queue_command(uint32_t seq, int16_t counts, uint8_t flags)
{
    fp_msg_t m;
    m.type = FP_MSG_COMMAND;
    m.u.command.session = SESSION;
    m.u.command.seq = seq;
    m.u.command.command = counts;
    m.u.command.flags = flags;
    queue(&m);
}

/* Fill the rest of this tick's bytes with COMMANDs the core must decode and then discard (stale). */
static void fill_with_stale(uint32_t seq)
{
    while (rx_len + FP_BODY_COMMAND + 5u <= sizeof rx) {
        queue_command(seq - 5u, 1000, FP_CMD_ENABLE);
    }
}

/* One device tick as the board's TIM5 interrupt runs it: received bytes, then fw_tick. */
static void tick(uint32_t k)
{
    size_t i;
    bench_mark(k);
    for (i = 0; i < rx_len; i++) {
        fw_rx_byte(&fw, rx[i]);
    }
    fw_tick(&fw);
    bench_mark(k);
    rx_len = 0u;
    hal.tx.tail = hal.tx.head; /* the UART sent it */
}

extern uint32_t _ebss, _estack;
#define STACK_PAINT 0xA5A5A5A5u

/* Paint from the end of .bss up to a little below the current stack pointer. */
static __attribute__((noinline)) void paint_stack(void)
{
    uintptr_t sp;
    uint32_t *p = &_ebss;
    __asm__ volatile("mov %0, sp" : "=r"(sp));
    while ((uintptr_t)p < sp - 128u) {
        *p++ = STACK_PAINT;
    }
}

/* Bytes of stack ever used: from the top of RAM down to the first word not still painted. */
static uint32_t stack_used(void)
{
    const uint32_t *p = &_ebss;
    while (*p == STACK_PAINT) {
        p++;
    }
    return (uint32_t)((uintptr_t)&_estack - (uintptr_t)p);
}

static void semihosting_write0(const char *text)
{
    register uint32_t r0 __asm__("r0") = 0x04u; /* SYS_WRITE0 */
    register const char *r1 __asm__("r1") = text;
    __asm__ volatile("bkpt 0xAB" : : "r"(r0), "r"(r1) : "memory");
}

static void print_stack_used(void)
{
    char text[32] = "stack_bytes ";
    char digits[11];
    uint32_t v = stack_used();
    size_t n = 0, at = 12;
    do {
        digits[n++] = (char)('0' + v % 10u);
        v /= 10u;
    } while (v);
    while (n) {
        text[at++] = digits[--n];
    }
    text[at++] = '\n';
    text[at] = '\0';
    semihosting_write0(text);
}

static void semihosting_exit(void)
{
    register uint32_t r0 __asm__("r0") = 0x18u;     /* SYS_EXIT */
    register uint32_t r1 __asm__("r1") = 0x20026u; /* ADP_Stopped_ApplicationExit */
    __asm__ volatile("bkpt 0xAB" : : "r"(r0), "r"(r1) : "memory");
}

int main(void)
{
    fp_msg_t m;
    uint32_t k;
    paint_stack();
    fw_init(&fw, &board, &hal);
    /* tick 1: 0x00, HELLO and CONFIG in one tick: HELLO_ACK + STATUS + SAMPLE 0 */
    rx[rx_len++] = 0u;
    m.type = FP_MSG_HELLO;
    m.u.hello.protocol_version = FP_PROTOCOL_VERSION;
    m.u.hello.schema_hash = FP_SCHEMA_HASH;
    m.u.hello.nonce = SESSION;
    queue(&m);
    m.type = FP_MSG_CONFIG;
    m.u.config.rate_hz = 1000u;
    m.u.config.watchdog_ms = 5u;
    queue(&m);
    fill_with_stale(0u);
    tick(1u);
    /* ticks 2-4: the answer plus stale COMMANDs filling the line */
    for (k = 2u; k <= 4u; k++) {
        queue_command(fw.seq - 1u, -32768, FP_CMD_ENABLE);
        fill_with_stale(fw.seq);
        tick(k);
    }
    /* ticks 5-10: silence: the watchdog trips (5 ms), θ and θ̇ at the rails, encoder fault */
    hal.theta = BOARD_ADC_MAX;
    hal.theta_dot = BOARD_ADC_MIN;
    hal.encoder_fault = 1u;
    for (k = 5u; k <= 10u; k++) {
        tick(k);
    }
    /* tick 11: CLEAR_FAULT with the causes gone: STATUS + SAMPLE, output zero */
    hal.theta = hal.theta_dot = 0;
    hal.encoder_fault = 0u;
    queue_command(fw.seq - 1u, 0, FP_CMD_CLEAR_FAULT);
    fill_with_stale(fw.seq);
    tick(11u);
    print_stack_used();
    semihosting_exit();
    return 0;
}
