/*
 * board_config.h - what this rig's DAQ reports in HELLO_ACK and the limits it enforces. Edit the
 * calibration for your sensors (FIRMWARE.md, "Calibration"); everything else follows from it.
 */
#ifndef BOARD_CONFIG_H
#define BOARD_CONFIG_H

#define BOARD_SYSCLK_HZ 84000000u  /* HSE (or HSI) -> PLL; APB1 42 MHz (timers 84 MHz), APB2 84 MHz */
/* The external clock, a whole number of MHz in 4..26 (0: none, the internal 16 MHz HSI). Nucleo-F401RE: the ST-LINK's
 * 8 MHz MCO, a clock input (BYPASS 1); Black Pill F401CC: a 25 MHz crystal (25000000u, BYPASS 0). If it does not
 * start, the board runs from the HSI. */
#define BOARD_HSE_HZ 8000000u
#define BOARD_HSE_BYPASS 1
#define BOARD_TIMER_HZ 84000000u   /* TIM2/5 kernel clock (APB1 x 2) and TIM1's (APB2) */
#define BOARD_UART_BAUD 1000000u   /* furuta-rt run --baud default */
#define BOARD_PWM_HZ 20000u        /* motor driver PWM, above hearing */
#define BOARD_DEFAULT_RATE_HZ 500u /* the thesis rig's loop; the host's CONFIG sets its own */
#define BOARD_MAX_RATE_HZ 2000u    /* SAMPLE 23 B + STATUS at 1 Mbaud: 2 kHz keeps the UART under 50 % */
#define BOARD_WATCHDOG_MS 20u
#define BOARD_IWDG_MS 50u          /* hardware watchdog: a hung firmware resets, and reset is zero drive */
/* The tick is the only IWDG refresh: its period (plus the longest tick) must stay under the IWDG's timeout with the
 * LSI at its fastest, 47 kHz (datasheet: 17-47 kHz): (50 + 1) x 32 / 47 kHz = 34.7 ms. CONFIG refuses slower. */
#define BOARD_MIN_RATE_HZ 50u
#define BOARD_LSI_MAX_HZ 47000u
/* The longest a COMMAND is held without host traffic that CONFIG accepts (the protocol allows 65 535 ms): a host
 * that stops talking leaves the motor driven for at most this long. */
#define BOARD_MAX_WATCHDOG_MS 500u

/* θ: an analog absolute angle sensor (e.g. AS5600's analog output, 0..3.3 V over one turn) on PA4;
 * counts are the 12-bit ADC reading minus 2048 (mid-scale), so the rails are -2048 and +2047. */
#define BOARD_THETA_RAD_PER_COUNT 0.0015339808f /* 2 pi / 4096 */
#define BOARD_THETA_OFFSET_COUNTS 0             /* counts at theta = 0 (upright): calibrate */
/* 1: θ's sensor covers a full turn and wraps (0 V follows 3.3 V: AS5600, a continuous-turn potentiometer), so a
 * reading at 0 or 4095 is the pendulum passing the wrap, not a rail; 0: it saturates at the rails (ADC_OVERRANGE). */
#define BOARD_THETA_WRAPS 1
/* θ from a quadrature encoder instead (the QUBE-Servo 2's 2048 counts per turn, ST's EDUKIT's 2400): its counts per
 * turn (x4), on TIM4 (PB6 = A, PB7 = B); 0: the analog sensor on PA4 above. Its zero is where the pendulum is at
 * power-up, which must be hanging still (θ = π); HELLO_ACK then reports 2 pi / CPR and offset 0, and the reading
 * wraps (describe the rig with theta_wraps = true). Set here or with BOARD_DEFINES at build time. */
#ifndef BOARD_THETA_ENCODER_CPR
#define BOARD_THETA_ENCODER_CPR 0u
#endif
/* θ̇: an analog differentiator (or tacho) on PB0, 0 rad/s at mid-scale. */
#define BOARD_THETA_DOT_RAD_S_PER_COUNT 0.01f /* +-20 rad/s over the ADC range */
#define BOARD_THETA_DOT_OFFSET_COUNTS 0
/* φ: quadrature encoder on TIM2 (PA0 = A, PA1 = B), x4: a 500-line encoder gives 2000 counts. */
#define BOARD_PHI_COUNTS_PER_REV 2000u
/* Actuator: PWM + direction into an H-bridge; full scale = the bridge's supply voltage. */
#define BOARD_ACTUATOR_FULL_SCALE 12.0f
#define BOARD_ACTUATOR_KIND FP_ACT_VOLTAGE_V

#define BOARD_ADC_MIN (-2048)
#define BOARD_ADC_MAX 2047

#endif /* BOARD_CONFIG_H */
