/*
 * regs.h - the few STM32F401 registers the port uses (RM0368), written out so the build needs no
 * vendor SDK. Addresses and bit positions are those of the STM32F401xB/C/D/E; the F411 shares them.
 */
#ifndef REGS_H
#define REGS_H

#include <stdint.h>

#define REG32(addr) (*(volatile uint32_t *)(uintptr_t)(addr))

/* RCC, FLASH */
#define RCC_BASE 0x40023800u
#define RCC_CR REG32(RCC_BASE + 0x00u)
#define RCC_PLLCFGR REG32(RCC_BASE + 0x04u)
#define RCC_CFGR REG32(RCC_BASE + 0x08u)
#define RCC_AHB1ENR REG32(RCC_BASE + 0x30u)
#define RCC_APB1ENR REG32(RCC_BASE + 0x40u)
#define RCC_CSR REG32(RCC_BASE + 0x74u)
#define RCC_CSR_RMVF (1u << 24)
#define RCC_CSR_RESET_FLAGS 0xFE000000u
#define RCC_CSR_BORRSTF (1u << 25)
#define RCC_CSR_PINRSTF (1u << 26)
#define RCC_CSR_PORRSTF (1u << 27)
#define RCC_CSR_SFTRSTF (1u << 28)
#define RCC_CSR_IWDGRSTF (1u << 29)
#define RCC_CSR_WWDGRSTF (1u << 30)
#define RCC_APB2ENR REG32(RCC_BASE + 0x44u)
#define RCC_CR_HSION (1u << 0)
#define RCC_CR_HSIRDY (1u << 1)
#define RCC_CR_HSEON (1u << 16)
#define RCC_CR_HSERDY (1u << 17)
#define RCC_CR_HSEBYP (1u << 18)
#define RCC_CR_PLLON (1u << 24)
#define RCC_PLLCFGR_PLLSRC_HSE (1u << 22)
#define RCC_CR_PLLRDY (1u << 25)
#define RCC_CFGR_SW_PLL 2u
#define RCC_CFGR_SWS_PLL (2u << 2)
#define RCC_CFGR_PPRE1_DIV2 (4u << 10)
#define RCC_AHB1ENR_GPIOA (1u << 0)
#define RCC_AHB1ENR_GPIOB (1u << 1)
#define RCC_AHB1ENR_DMA1 (1u << 21)
#define RCC_APB1ENR_TIM2 (1u << 0)
#define RCC_APB1ENR_TIM4 (1u << 2)
#define RCC_APB1ENR_TIM5 (1u << 3)
#define RCC_APB1ENR_USART2 (1u << 17)
#define RCC_APB2ENR_TIM1 (1u << 0)
#define RCC_APB2ENR_ADC1 (1u << 8)
#define FLASH_ACR REG32(0x40023C00u)
#define FLASH_ACR_2WS_CACHES (2u | (1u << 8) | (1u << 9) | (1u << 10)) /* latency 2, prefetch, I and D cache */

/* GPIO */
#define GPIOA_BASE 0x40020000u
#define GPIOB_BASE 0x40020400u
#define GPIO_MODER(b) REG32((b) + 0x00u)
#define GPIO_OSPEEDR(b) REG32((b) + 0x08u)
#define GPIO_PUPDR(b) REG32((b) + 0x0Cu)
#define GPIO_ODR(b) REG32((b) + 0x14u)
#define GPIO_BSRR(b) REG32((b) + 0x18u)
#define GPIO_AFRL(b) REG32((b) + 0x20u)
#define GPIO_AFRH(b) REG32((b) + 0x24u)
#define GPIO_MODE_OUT 1u
#define GPIO_MODE_AF 2u
#define GPIO_MODE_ANALOG 3u

/* timers: TIM1 (advanced, 16-bit, APB2), general-purpose TIM2 and TIM5 (32-bit), TIM4 (16-bit) */
#define TIM1_BASE 0x40010000u
#define TIM2_BASE 0x40000000u
#define TIM4_BASE 0x40000800u
#define TIM5_BASE 0x40000C00u
#define TIM_CR1(b) REG32((b) + 0x00u)
#define TIM_CR2(b) REG32((b) + 0x04u)
#define TIM_SMCR(b) REG32((b) + 0x08u)
#define TIM_DIER(b) REG32((b) + 0x0Cu)
#define TIM_SR(b) REG32((b) + 0x10u)
#define TIM_EGR(b) REG32((b) + 0x14u)
#define TIM_CCMR1(b) REG32((b) + 0x18u)
#define TIM_CCER(b) REG32((b) + 0x20u)
#define TIM_CNT(b) REG32((b) + 0x24u)
#define TIM_PSC(b) REG32((b) + 0x28u)
#define TIM_ARR(b) REG32((b) + 0x2Cu)
#define TIM_CCR1(b) REG32((b) + 0x34u)
#define TIM_BDTR(b) REG32((b) + 0x44u) /* TIM1 only */
#define TIM_CR1_CEN (1u << 0)
#define TIM_CR1_URS (1u << 2)
#define TIM_CR1_ARPE (1u << 7)
#define TIM_DIER_UIE (1u << 0)
#define TIM_SR_UIF (1u << 0)
#define TIM_EGR_UG (1u << 0)
#define TIM_CR2_MMS_UPDATE (2u << 4)
#define TIM_BDTR_OSSI (1u << 10)
#define TIM_BDTR_MOE (1u << 15)

/* ADC1 and the ADC common registers */
#define ADC1_BASE 0x40012000u
#define ADC1_SR REG32(ADC1_BASE + 0x00u)
#define ADC1_CR1 REG32(ADC1_BASE + 0x04u)
#define ADC1_CR2 REG32(ADC1_BASE + 0x08u)
#define ADC1_SMPR2 REG32(ADC1_BASE + 0x10u)
#define ADC1_JSQR REG32(ADC1_BASE + 0x38u)
#define ADC1_JDR1 REG32(ADC1_BASE + 0x3Cu)
#define ADC1_JDR2 REG32(ADC1_BASE + 0x40u)
#define ADC_CCR REG32(0x40012304u)
#define ADC_SR_JEOC (1u << 2)
#define ADC_SR_JSTRT (1u << 3)
#define ADC_CR1_SCAN (1u << 8)
#define ADC_CR2_ADON (1u << 0)
#define ADC_CR2_JSWSTART (1u << 22)
#define ADC_CR2_JEXTEN_RISING (1u << 20)
#define ADC_CR2_JEXTSEL_TIM5_TRGO (11u << 16)

/* USART2 */
/* DMA1 stream 6, channel 4: USART2_TX (RM0368 table 27) */
#define DMA1_BASE 0x40026000u
#define DMA1_HISR REG32(DMA1_BASE + 0x04u)
#define DMA1_HIFCR REG32(DMA1_BASE + 0x0Cu)
#define DMA1_S6CR REG32(DMA1_BASE + 0xA0u)
#define DMA1_S6NDTR REG32(DMA1_BASE + 0xA4u)
#define DMA1_S6PAR REG32(DMA1_BASE + 0xA8u)
#define DMA1_S6M0AR REG32(DMA1_BASE + 0xACu)
#define DMA_HISR_STREAM6 (0x3Du << 16) /* FEIF6, DMEIF6, TEIF6, HTIF6, TCIF6 */
#define DMA_HISR_TCIF6 (1u << 21)
#define DMA_SCR_EN (1u << 0)
#define DMA_SCR_TCIE (1u << 4)
#define DMA_SCR_DIR_M2P (1u << 6)
#define DMA_SCR_MINC (1u << 10)
#define DMA_SCR_CHSEL_4 (4u << 25)

#define USART2_BASE 0x40004400u
#define USART2_SR REG32(USART2_BASE + 0x00u)
#define USART2_DR REG32(USART2_BASE + 0x04u)
#define USART2_BRR REG32(USART2_BASE + 0x08u)
#define USART2_CR1 REG32(USART2_BASE + 0x0Cu)
#define USART2_CR3 REG32(USART2_BASE + 0x14u)
#define USART_CR3_DMAT (1u << 7)
#define USART_SR_PE (1u << 0)
#define USART_SR_FE (1u << 1)
#define USART_SR_NF (1u << 2)
#define USART_SR_ORE (1u << 3)
#define USART_SR_RXNE (1u << 5)
#define USART_SR_TXE (1u << 7)
#define USART_CR1_RE (1u << 2)
#define USART_CR1_TE (1u << 3)
#define USART_CR1_RXNEIE (1u << 5)
#define USART_CR1_TXEIE (1u << 7)
#define USART_CR1_UE (1u << 13)

/* independent watchdog */
#define IWDG_KR REG32(0x40003000u)
#define IWDG_PR REG32(0x40003004u)
#define IWDG_RLR REG32(0x40003008u)

/* core: NVIC, DWT cycle counter, unique id */
#define NVIC_ISER(n) REG32(0xE000E100u + 4u * (n))
#define NVIC_ICPR(n) REG32(0xE000E280u + 4u * (n))
#define NVIC_IPR8(irq) (*(volatile uint8_t *)(uintptr_t)(0xE000E400u + (irq)))
#define SYST_CSR REG32(0xE000E010u) /* SysTick: ENABLE bit 0, TICKINT bit 1, CLKSOURCE (CPU) bit 2 */
#define SYST_RVR REG32(0xE000E014u)
#define SYST_CVR REG32(0xE000E018u)
#define DEMCR REG32(0xE000EDFCu)
#define DWT_CTRL REG32(0xE0001000u)
#define DWT_CYCCNT REG32(0xE0001004u)
#define UID_BASE 0x1FFF7A10u
/* what a debugger halt stops (RM0368 23.16): counters, the IWDG; TIM1's outputs go off as with MOE = 0 */
#define DBGMCU_APB1_FZ REG32(0xE0042008u)
#define DBGMCU_APB2_FZ REG32(0xE004200Cu)
#define DBG_TIM5_STOP (1u << 3)
#define DBG_IWDG_STOP (1u << 12)
#define DBG_TIM1_STOP (1u << 0)

#define IRQ_DMA1_STREAM6 17u
#define IRQ_TIM2 28u
#define IRQ_TIM3 29u
#define IRQ_USART2 38u
#define IRQ_TIM5 50u
#define IRQ_COUNT 86u /* F401: positions 0..85 (SPI4 = 84, 85 reserved) */

#endif /* REGS_H */
