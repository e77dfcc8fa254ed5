/*
 * board.c - the firmware core on an STM32F401 (Black Pill / Nucleo-F401RE), register level.
 *
 *   TIM5 update IRQ  the device tick at rate_hz: latch φ, take θ/θ̇ (converted at the update event itself), feed
 *                    the bytes USART2 received to the core, fw_tick (SAMPLE out, COMMAND applied), refresh the
 *                    IWDG; a period that elapsed during the tick is reported as an overrun (fw_skip)
 *   USART2 IRQ       higher priority: received bytes into rx_ring, their errors counted (1 Mbaud, 8N1)
 *   DMA1 stream 6    sends the frames a tick queued (USART2_TX, channel 4), one transfer per tick: the tick's frames go
 *                    into one of two buffers, started at the tick's end; frames queued while the line is busy with
 *                    the previous transfer start when it completes (its interrupt, at the tick's priority)
 *   TIM2             quadrature encoder (PA0 = A, PA1 = B), 32-bit count
 *   ADC1 injected    θ on PA4 (IN4), θ̇ on PB0 (IN8), 12 bit, triggered by TIM5's update (TRGO): sampled at the
 *                    period's start whatever the software does, φ read at the handler's first instruction
 *   TIM1 CH1         PWM on PA8 at 20 kHz, direction on PA7; the advanced timer because its main output (MOE) goes
 *                    off — the pin driven low — when a fault handler clears it or a debugger halts the core
 *   IWDG             50 ms: a hung firmware resets, and reset leaves the PWM pin an input (zero drive)
 *   faults           any unexpected exception (HardFault too) drives the PWM pin low before it spins (startup.c)
 *   debugger halt    TIM1's output off, the tick and the IWDG stopped (DBGMCU): no drive, no reset, no overrun
 *
 * Only the tick touches the core (fw_t), so it needs no locks. No floating point anywhere here.
 */
#include <stdint.h>
#include <string.h> /* memcpy */

#include "board_config.h"
#include "fw_core.h"
#include "regs.h"
#include "ring.h"

#define PWM_TOP (BOARD_TIMER_HZ / BOARD_PWM_HZ) /* 4200 timer counts per PWM period */
#if BOARD_THETA_ENCODER_CPR
/* θ from TIM4's count, which wraps with the pendulum's turn: counts from upright in [-CPR/2, CPR/2) */
#define THETA_RAD_PER_COUNT (6.2831853f / (float)BOARD_THETA_ENCODER_CPR)
#define THETA_OFFSET_COUNTS 0
typedef char theta_encoder_cpr_fits[(BOARD_THETA_ENCODER_CPR % 2u == 0u && BOARD_THETA_ENCODER_CPR <= 65536u) ? 1 : -1];
#else
#define THETA_RAD_PER_COUNT BOARD_THETA_RAD_PER_COUNT
#define THETA_OFFSET_COUNTS BOARD_THETA_OFFSET_COUNTS
#endif
#if BOARD_THETA_WRAPS || BOARD_THETA_ENCODER_CPR
#define THETA_RAIL_MIN (-(1L << 20)) /* a wrapping θ has no rail: outside every reading */
#define THETA_RAIL_MAX (1L << 20)
#else
#define THETA_RAIL_MIN BOARD_ADC_MIN
#define THETA_RAIL_MAX BOARD_ADC_MAX
#endif
#define HSI_HZ 16000000u
#define HSE_WAIT_LOOPS 100000u /* > 10 ms at 16 MHz; a crystal starts in ~2 ms, an external clock at once */
typedef char hse_divides_to_1_mhz[(BOARD_HSE_HZ == 0u || (BOARD_HSE_HZ % 1000000u == 0u && BOARD_HSE_HZ >= 4000000u &&
                                                          BOARD_HSE_HZ <= 26000000u)) ? 1 : -1];
#define ADC_WAIT_LOOPS 1000u /* > 60 µs; the two conversions take 6.5 µs from the update event */
#define PIN_PWM 8u                              /* PA8 = TIM1_CH1 (AF1) */
#define PIN_DIR 7u                              /* PA7 */
#define PWM_TIM TIM1_BASE

#define TX_DMA_BYTES 256u /* one tick's frames: HELLO_ACK + STATUS + SAMPLE are 106 bytes */

struct fw_hal {
    ring_t rx;
    uint8_t tx_fill;        /* the buffer frames are queued into; the other one may be on the line */
    uint16_t tx_len[2];     /* bytes queued in each buffer */
    int32_t phi;                /* latched at the top of the tick */
    int16_t theta, theta_dot;   /* converted at the tick's update event */
    uint32_t adc_missed;        /* ticks whose conversion never ended (a rail reported instead) */
    uint32_t rx_overflows;
    uint32_t tick_cycles_max; /* worst tick in CPU cycles (DWT), for a debugger: FIRMWARE.md */
    uint32_t clock_source_hz; /* BOARD_HSE_HZ, or 16 MHz when the HSE did not start (for a debugger) */
};

static fw_hal_t hal;
static fw_t fw;
static uint8_t tx_buf[2][TX_DMA_BYTES];
/* RCC_CSR's reset flags at start-up (1 << 29: the IWDG reset the board, 1 << 27: power-on, 1 << 26: the reset pin)
 * and what HELLO_ACK reports of them; the receiver's errors the USART reported (bytes lost to an overrun; framing,
 * noise and parity errors), which STATUS reports */
static volatile uint32_t reset_flags;
static uint8_t reset_cause;
static volatile uint32_t uart_overruns, uart_line_errors;
/* Set by the fault handler before it spins (board_stop_drive), in RAM the start-up code leaves alone (a system reset
 * keeps SRAM): the watchdog reset that follows is reported as a fault */
#define FAULT_MARK 0xFA017ED5u
__attribute__((section(".noinit"))) static volatile uint32_t fault_mark;
static const fw_board_t board = {
    0u, /* device_id: from the MCU's unique id at start-up, see main() */
    BOARD_DEFAULT_RATE_HZ,
    BOARD_MAX_RATE_HZ,
    BOARD_WATCHDOG_MS,
    THETA_RAD_PER_COUNT,
    THETA_OFFSET_COUNTS,
    BOARD_THETA_DOT_RAD_S_PER_COUNT,
    BOARD_THETA_DOT_OFFSET_COUNTS,
    BOARD_PHI_COUNTS_PER_REV,
    BOARD_ACTUATOR_FULL_SCALE,
    BOARD_ACTUATOR_KIND,
    THETA_RAIL_MIN, /* the rails of the readings, whatever the offsets */
    THETA_RAIL_MAX,
    BOARD_ADC_MIN,
    BOARD_ADC_MAX,
    BOARD_MIN_RATE_HZ,
    BOARD_MAX_WATCHDOG_MS,
};
/* the slowest tick (1 ms for the tick itself) refreshes the IWDG in time with the LSI at its fastest */
typedef char slowest_tick_refreshes_the_iwdg[((1000u / BOARD_MIN_RATE_HZ + 1u) * BOARD_LSI_MAX_HZ <
                                              (BOARD_IWDG_MS + 1u) * 32000u) ? 1 : -1];
static fw_board_t board_with_id;

void TIM5_IRQHandler(void);
void USART2_IRQHandler(void);
void DMA1_Stream6_IRQHandler(void);
int main(void);

/* ---- HAL ------------------------------------------------------------------------------------ */

int32_t hal_encoder_count(fw_hal_t *h) { return h->phi; }

uint8_t hal_encoder_fault(fw_hal_t *h)
{
    (void)h;
    return 0u; /* TIM encoder mode does not flag illegal transitions */
}

static int16_t adc_counts(uint32_t dr) { return (int16_t)((int32_t)(dr & 0xFFFu) - 2048); }

int16_t hal_adc_theta(fw_hal_t *h) { return h->theta; }

int16_t hal_adc_theta_dot(fw_hal_t *h) { return h->theta_dot; }

/* The injected conversions TIM5's update started (6.5 µs for both): read once they end. A conversion that never
 * ends (the trigger lost) reports the rails, so the core latches ADC_OVERRANGE (θ̇ has a rail) and drives zero. */
static void latch_adc(fw_hal_t *h)
{
    uint32_t n = 0u;
    while (!(ADC1_SR & ADC_SR_JEOC)) {
        if (++n > ADC_WAIT_LOOPS) {
            h->theta = BOARD_ADC_MIN;
            h->theta_dot = BOARD_ADC_MIN;
            h->adc_missed++;
            return;
        }
    }
    ADC1_SR = ~(ADC_SR_JEOC | ADC_SR_JSTRT);
    h->theta = adc_counts(ADC1_JDR1);
    h->theta_dot = adc_counts(ADC1_JDR2);
}

/* A UG of TIM5 is an update event, hence a TRGO and a conversion outside the tick's instant: wait for it to end and
 * drop it, so the next tick does not take its JEOC (set early) for its own conversion's and read a stale θ. */
static void discard_conversion(void)
{
    uint32_t n = 0u;
    while (!(ADC1_SR & ADC_SR_JEOC) && ++n <= ADC_WAIT_LOOPS) {
    }
    ADC1_SR = ~(ADC_SR_JEOC | ADC_SR_JSTRT);
}

#if BOARD_THETA_ENCODER_CPR
/* θ from the pendulum's encoder: TIM4 counts 0..CPR-1 from where the pendulum hung at power-up (θ = π), so upright
 * is CPR/2 and the reading is the count minus that. */
static int16_t theta_from_encoder(void)
{
    return (int16_t)((int32_t)TIM_CNT(TIM4_BASE) - (int32_t)(BOARD_THETA_ENCODER_CPR / 2u));
}
#endif

void hal_actuator_write(fw_hal_t *h, int16_t counts)
{
    uint32_t mag = (uint32_t)(counts < 0 ? -(int32_t)counts : (int32_t)counts);
    uint32_t dir_high = (GPIO_ODR(GPIOA_BASE) >> PIN_DIR) & 1u;
    (void)h;
    if ((counts > 0) != (dir_high != 0u)) {
        /* direction change: the duty runs from a preload, so the old duty would drive the new direction until the
         * PWM period ends; zero it now (UG transfers the preload and restarts the period with the output low), then
         * turn the bridge round while it does not drive */
        TIM_CCR1(PWM_TIM) = 0u;
        TIM_EGR(PWM_TIM) = TIM_EGR_UG;
        GPIO_BSRR(GPIOA_BASE) = counts > 0 ? (1u << PIN_DIR) : (1u << (PIN_DIR + 16u));
    }
    TIM_CCR1(PWM_TIM) = mag * PWM_TOP / 32767u;
}

uint8_t hal_uart_write(fw_hal_t *h, const uint8_t *data, size_t len)
{
    uint8_t f = h->tx_fill;
    if (len > TX_DMA_BYTES - h->tx_len[f]) {
        return 0u;
    }
    memcpy(&tx_buf[f][h->tx_len[f]], data, len);
    h->tx_len[f] = (uint16_t)(h->tx_len[f] + len);
    return 1u;
}

/* Start sending the queued frames if the line is free: DMA1 stream 6 takes the filled buffer, the other one takes
 * the next frames. Called at the end of the tick and by the transfer's completion, both at the tick's priority (no
 * interrupt between the two, none while the tick queues). */
static void uart_tx_kick(void)
{
    uint8_t f = hal.tx_fill;
    if (hal.tx_len[f] == 0u || (DMA1_S6CR & DMA_SCR_EN)) {
        return;
    }
    DMA1_HIFCR = DMA_HISR_STREAM6; /* a stream starts with its flags clear */
    DMA1_S6M0AR = (uint32_t)(uintptr_t)tx_buf[f];
    DMA1_S6NDTR = hal.tx_len[f];
    DMA1_S6CR = DMA_SCR_CHSEL_4 | DMA_SCR_MINC | DMA_SCR_DIR_M2P | DMA_SCR_TCIE | DMA_SCR_EN;
    f ^= 1u;
    hal.tx_fill = f;
    hal.tx_len[f] = 0u;
}

void hal_tick_rate(fw_hal_t *h, uint16_t rate_hz)
{
    uint32_t arr = BOARD_TIMER_HZ / rate_hz - 1u;
    uint32_t cnt;
    (void)h;
    /* ARR is preloaded (ARPE): a value below the running count can never be in force, which would run the counter
     * to its 32-bit wrap (51 s without a tick). The core counts the new period from this tick, so it takes effect
     * now: UG transfers it (URS: no update interrupt), and the count goes back to where it was, or to the last count
     * of the new period when the tick has already run longer than that (its update comes at once: an overrun) */
    TIM_ARR(TIM5_BASE) = arr;
    cnt = TIM_CNT(TIM5_BASE);
    TIM_EGR(TIM5_BASE) = TIM_EGR_UG;
    TIM_CNT(TIM5_BASE) = cnt < arr ? cnt : arr;
    discard_conversion();
}

void hal_session_started(fw_hal_t *h, uint8_t new_session)
{
    (void)h;
    (void)new_session;
}

uint8_t hal_reset_cause(fw_hal_t *h)
{
    (void)h;
    return reset_cause;
}

void hal_uart_errors(fw_hal_t *h, uint32_t *overruns, uint32_t *line_errors)
{
    *overruns = uart_overruns + h->rx_overflows; /* lost in the USART, or to a full receive ring */
    *line_errors = uart_line_errors;
}

/* ---- interrupts ------------------------------------------------------------------------------ */

void TIM5_IRQHandler(void)
{
    uint32_t t0 = DWT_CYCCNT;
    uint32_t cycles;
    int byte;
    hal.phi = (int32_t)TIM_CNT(TIM2_BASE); /* first: θ and θ̇ were sampled at the update event */
#if BOARD_THETA_ENCODER_CPR
    {
        int16_t theta = theta_from_encoder();
        latch_adc(&hal);
        hal.theta = theta;
    }
#else
    latch_adc(&hal); /* before the received bytes: a CONFIG's UG triggers another conversion */
#endif
    TIM_SR(TIM5_BASE) = ~TIM_SR_UIF;
    while ((byte = ring_get(&hal.rx)) >= 0) {
        fw_rx_byte(&fw, (uint8_t)byte);
    }
    fw_tick(&fw);
    uart_tx_kick();
    IWDG_KR = 0xAAAAu;
    if (TIM_SR(TIM5_BASE) & TIM_SR_UIF) { /* a whole period went by during this tick: skipped, counted once */
        TIM_SR(TIM5_BASE) = ~TIM_SR_UIF;
        (void)TIM_SR(TIM5_BASE); /* the write reaches the timer (the line drops) before the pending bit is cleared */
        NVIC_ICPR(IRQ_TIM5 / 32u) = 1u << (IRQ_TIM5 % 32u); /* else the handler runs again at once for that period */
        fw_skip(&fw, 1u);
    }
    cycles = DWT_CYCCNT - t0;
    if (cycles > hal.tick_cycles_max) {
        hal.tick_cycles_max = cycles;
    }
}

void USART2_IRQHandler(void)
{
    uint32_t sr = USART2_SR;
    if (sr & USART_SR_ORE) {
        uart_overruns++;
    }
    if (sr & (USART_SR_FE | USART_SR_NF | USART_SR_PE)) {
        uart_line_errors++; /* the byte is passed on: its frame fails the CRC */
    }
    if (sr & (USART_SR_RXNE | USART_SR_ORE)) {
        uint8_t byte = (uint8_t)USART2_DR; /* also clears ORE */
        if (!ring_put(&hal.rx, byte)) {
            hal.rx_overflows++;
        }
    }
}

void DMA1_Stream6_IRQHandler(void)
{
    DMA1_HIFCR = DMA_HISR_STREAM6; /* the transfer is complete (the stream has cleared EN) */
    uart_tx_kick();                /* the frames queued meanwhile */
}

/* ---- set-up ---------------------------------------------------------------------------------- */

/* 84 MHz through the PLL from the board's external clock (BOARD_HSE_HZ), or from the internal 16 MHz HSI (±1 %, worse
 * over temperature) when the board has none or it does not start; returns the frequency of the source used. */
static uint32_t clock_84mhz(void)
{
    uint32_t source_hz = HSI_HZ;
    uint32_t pllsrc = 0u;
    RCC_CR |= RCC_CR_HSION;
    while (!(RCC_CR & RCC_CR_HSIRDY)) {
    }
#if BOARD_HSE_HZ
    {
        uint32_t n;
        if (BOARD_HSE_BYPASS) {
            RCC_CR |= RCC_CR_HSEBYP; /* only while the HSE is off */
        }
        RCC_CR |= RCC_CR_HSEON;
        for (n = 0u; n < HSE_WAIT_LOOPS && !(RCC_CR & RCC_CR_HSERDY); n++) {
        }
        if (RCC_CR & RCC_CR_HSERDY) {
            source_hz = BOARD_HSE_HZ;
            pllsrc = RCC_PLLCFGR_PLLSRC_HSE;
        } else {
            RCC_CR &= ~RCC_CR_HSEON; /* no clock there: run from the HSI */
            RCC_CR &= ~RCC_CR_HSEBYP;
        }
    }
#endif
    FLASH_ACR = FLASH_ACR_2WS_CACHES;
    /* source / M (1 MHz) * N 336 / P 4 = 84 MHz; Q 7 -> 48 MHz */
    RCC_PLLCFGR = (source_hz / 1000000u) | (336u << 6) | (1u << 16) | pllsrc | (7u << 24);
    RCC_CR |= RCC_CR_PLLON;
    while (!(RCC_CR & RCC_CR_PLLRDY)) {
    }
    RCC_CFGR = RCC_CFGR_PPRE1_DIV2 | RCC_CFGR_SW_PLL;
    while ((RCC_CFGR & (3u << 2)) != RCC_CFGR_SWS_PLL) {
    }
    return source_hz;
}

static void pin_mode(uint32_t port, uint32_t pin, uint32_t mode, uint32_t af)
{
    GPIO_MODER(port) = (GPIO_MODER(port) & ~(3u << (2u * pin))) | (mode << (2u * pin));
    if (mode == GPIO_MODE_AF) {
        if (pin < 8u) {
            GPIO_AFRL(port) = (GPIO_AFRL(port) & ~(15u << (4u * pin))) | (af << (4u * pin));
        } else {
            GPIO_AFRH(port) = (GPIO_AFRH(port) & ~(15u << (4u * (pin - 8u)))) | (af << (4u * (pin - 8u)));
        }
        GPIO_OSPEEDR(port) |= 2u << (2u * pin);
    }
}

/* Called by the fault handler (startup.c) before it spins, in whatever state the board is: the PWM pin low at once,
 * driven by the GPIO (the timer's main output off too), direction low. Touches only what is clocked. */
void board_stop_drive(void)
{
    fault_mark = FAULT_MARK;
    if (RCC_APB2ENR & RCC_APB2ENR_TIM1) {
        TIM_BDTR(PWM_TIM) &= ~TIM_BDTR_MOE; /* the output to its idle level, low (OSSI, OIS1 = 0) */
        TIM_CCR1(PWM_TIM) = 0u;
    }
    if (RCC_AHB1ENR & RCC_AHB1ENR_GPIOA) {
        GPIO_BSRR(GPIOA_BASE) = (1u << (PIN_PWM + 16u)) | (1u << (PIN_DIR + 16u));
        pin_mode(GPIOA_BASE, PIN_PWM, GPIO_MODE_OUT, 0u);
    }
}

static void peripherals(void)
{
    RCC_AHB1ENR |= RCC_AHB1ENR_GPIOA | RCC_AHB1ENR_GPIOB | RCC_AHB1ENR_DMA1;
    RCC_APB1ENR |= RCC_APB1ENR_TIM2 | RCC_APB1ENR_TIM5 | RCC_APB1ENR_USART2;
    RCC_APB2ENR |= RCC_APB2ENR_ADC1 | RCC_APB2ENR_TIM1;

    /* a debugger halt: TIM1's output off (zero drive), the tick and the IWDG stopped (no overrun, no reset while
     * stepping); the encoder counts on */
    DBGMCU_APB1_FZ |= DBG_TIM5_STOP | DBG_IWDG_STOP;
    DBGMCU_APB2_FZ |= DBG_TIM1_STOP;

    /* actuator first: direction low, PWM 0 */
    GPIO_BSRR(GPIOA_BASE) = 1u << (PIN_DIR + 16u);
    pin_mode(GPIOA_BASE, PIN_DIR, GPIO_MODE_OUT, 0u);
    TIM_PSC(PWM_TIM) = 0u;
    TIM_ARR(PWM_TIM) = PWM_TOP - 1u;
    TIM_CCR1(PWM_TIM) = 0u;
    TIM_CCMR1(PWM_TIM) = (6u << 4) | (1u << 3); /* OC1: PWM mode 1, preload */
    TIM_CCER(PWM_TIM) = 1u;                     /* CC1E */
    TIM_BDTR(PWM_TIM) = TIM_BDTR_MOE | TIM_BDTR_OSSI; /* main output on; off (fault, halt) = driven to OIS1 = low */
    TIM_EGR(PWM_TIM) = TIM_EGR_UG;
    TIM_CR1(PWM_TIM) = TIM_CR1_ARPE | TIM_CR1_CEN;
    pin_mode(GPIOA_BASE, PIN_PWM, GPIO_MODE_AF, 1u);

    /* encoder: TIM2 encoder mode 3 (both edges of both channels), input filter 8 samples */
    GPIO_PUPDR(GPIOA_BASE) |= (1u << 0) | (1u << 2); /* pull-ups on PA0, PA1 (open-collector encoders) */
    pin_mode(GPIOA_BASE, 0u, GPIO_MODE_AF, 1u);
    pin_mode(GPIOA_BASE, 1u, GPIO_MODE_AF, 1u);
    TIM_CCMR1(TIM2_BASE) = 1u | (3u << 4) | (1u << 8) | (3u << 12); /* CC1S = TI1, CC2S = TI2, IC1F = IC2F = 3 */
    TIM_SMCR(TIM2_BASE) = 3u;                                       /* SMS = encoder mode 3 */
    TIM_ARR(TIM2_BASE) = 0xFFFFFFFFu;
    TIM_CR1(TIM2_BASE) = TIM_CR1_CEN;
#if BOARD_THETA_ENCODER_CPR
    /* pendulum encoder: TIM4 encoder mode 3 on PB6 (A) / PB7 (B), the count wrapping at one turn */
    RCC_APB1ENR |= RCC_APB1ENR_TIM4;
    GPIO_PUPDR(GPIOB_BASE) |= (1u << 12) | (1u << 14);
    pin_mode(GPIOB_BASE, 6u, GPIO_MODE_AF, 2u);
    pin_mode(GPIOB_BASE, 7u, GPIO_MODE_AF, 2u);
    TIM_CCMR1(TIM4_BASE) = 1u | (3u << 4) | (1u << 8) | (3u << 12);
    TIM_SMCR(TIM4_BASE) = 3u;
    TIM_ARR(TIM4_BASE) = BOARD_THETA_ENCODER_CPR - 1u;
    TIM_CR1(TIM4_BASE) = TIM_CR1_CEN;
#endif

    /* ADC1: injected sequence IN4 (θ) then IN8 (θ̇), 56-cycle sampling, ADC clock 84 / 4 = 21 MHz */
    pin_mode(GPIOA_BASE, 4u, GPIO_MODE_ANALOG, 0u);
    pin_mode(GPIOB_BASE, 0u, GPIO_MODE_ANALOG, 0u);
    ADC_CCR = 1u << 16;
    ADC1_SMPR2 = (3u << (3u * 4u)) | (3u << (3u * 8u));
    ADC1_CR1 = ADC_CR1_SCAN;
    ADC1_JSQR = (1u << 20) | (4u << 10) | (8u << 15); /* JL = 1 (two), JSQ3 = 4, JSQ4 = 8 */
    ADC1_CR2 = ADC_CR2_ADON | ADC_CR2_JEXTEN_RISING | ADC_CR2_JEXTSEL_TIM5_TRGO; /* converts at each tick's start */

    /* USART2 on PA2 (TX) / PA3 (RX): the Nucleo's ST-LINK virtual COM port */
    pin_mode(GPIOA_BASE, 2u, GPIO_MODE_AF, 7u);
    pin_mode(GPIOA_BASE, 3u, GPIO_MODE_AF, 7u);
    USART2_BRR = (BOARD_SYSCLK_HZ / 2u + BOARD_UART_BAUD / 2u) / BOARD_UART_BAUD;
    USART2_CR1 = USART_CR1_UE | USART_CR1_TE | USART_CR1_RE | USART_CR1_RXNEIE;
    USART2_CR3 = USART_CR3_DMAT; /* transmit requests go to DMA1 stream 6 */
    DMA1_S6PAR = (uint32_t)(uintptr_t)&USART2_DR;

    /* the tick: TIM5 update at the default rate (fw_init calls hal_tick_rate) */
    TIM_PSC(TIM5_BASE) = 0u;
    TIM_CR1(TIM5_BASE) = TIM_CR1_ARPE | TIM_CR1_URS;
    TIM_CR2(TIM5_BASE) = TIM_CR2_MMS_UPDATE; /* the update event is TRGO: the ADC's trigger */
    TIM_DIER(TIM5_BASE) = TIM_DIER_UIE;
    NVIC_IPR8(IRQ_USART2) = 0x40u; /* bytes must not wait for a tick */
    NVIC_IPR8(IRQ_TIM5) = 0x80u;
    NVIC_IPR8(IRQ_DMA1_STREAM6) = 0x80u; /* the tick's: it never pre-empts the tick queuing frames */
    NVIC_ISER(IRQ_DMA1_STREAM6 / 32u) = 1u << (IRQ_DMA1_STREAM6 % 32u);
    NVIC_ISER(IRQ_USART2 / 32u) = 1u << (IRQ_USART2 % 32u);
    NVIC_ISER(IRQ_TIM5 / 32u) = 1u << (IRQ_TIM5 % 32u);

    /* cycle counter for tick_cycles_max */
    DEMCR |= 1u << 24;
    DWT_CYCCNT = 0u;
    DWT_CTRL |= 1u;
}

static void hardware_watchdog(void)
{
    IWDG_KR = 0xCCCCu; /* start; LSI ~32 kHz / 32 = ~1 kHz */
    IWDG_KR = 0x5555u;
    IWDG_PR = 3u;
    IWDG_RLR = BOARD_IWDG_MS;
    IWDG_KR = 0xAAAAu;
}

/* HELLO_ACK's reset_cause from RCC_CSR's flags (RM0368 6.3.21; a power-on sets PINRSTF too) and the fault mark. */
static uint8_t reset_cause_of(uint32_t flags, uint32_t mark)
{
    if (flags & (RCC_CSR_PORRSTF | RCC_CSR_BORRSTF)) {
        return FP_RESET_POWER_ON;
    }
    if (flags & (RCC_CSR_IWDGRSTF | RCC_CSR_WWDGRSTF)) {
        return mark == FAULT_MARK ? FP_RESET_FAULT : FP_RESET_WATCHDOG;
    }
    if (flags & RCC_CSR_SFTRSTF) {
        return FP_RESET_SOFTWARE;
    }
    return (flags & RCC_CSR_PINRSTF) ? FP_RESET_PIN : FP_RESET_UNKNOWN;
}

int main(void)
{
    reset_flags = RCC_CSR & RCC_CSR_RESET_FLAGS;
    RCC_CSR |= RCC_CSR_RMVF; /* the next reset's flags alone */
    reset_cause = reset_cause_of(reset_flags, fault_mark);
    fault_mark = 0u;
    hal.clock_source_hz = clock_84mhz();
    board_with_id = board;
    board_with_id.device_id = REG32(UID_BASE) ^ REG32(UID_BASE + 4u) ^ REG32(UID_BASE + 8u);
    peripherals();
    fw_init(&fw, &board_with_id, &hal);
    hardware_watchdog();
    TIM_EGR(TIM5_BASE) = TIM_EGR_UG;
    TIM_SR(TIM5_BASE) = 0u;
    discard_conversion();
    TIM_CR1(TIM5_BASE) |= TIM_CR1_CEN;
    for (;;) {
        __asm__ volatile("wfi");
    }
}
