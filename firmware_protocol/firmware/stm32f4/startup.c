/*
 * startup.c - vector table and reset handler for the STM32F401 port (no vendor startup code).
 */
#include <stdint.h>
#include <string.h>

#include "regs.h"

extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss, _estack;
int main(void);
void Reset_Handler(void);
void Default_Handler(void);
void board_stop_drive(void);
/* Handlers a board defines; where it does not, the default one. */
void SysTick_Handler(void) __attribute__((weak, alias("Default_Handler")));
void TIM5_IRQHandler(void) __attribute__((weak, alias("Default_Handler")));
void USART2_IRQHandler(void) __attribute__((weak, alias("Default_Handler")));
void DMA1_Stream6_IRQHandler(void) __attribute__((weak, alias("Default_Handler")));

void Reset_Handler(void)
{
    memcpy(&_sdata, &_sidata, (size_t)((uintptr_t)&_edata - (uintptr_t)&_sdata));
    memset(&_sbss, 0, (size_t)((uintptr_t)&_ebss - (uintptr_t)&_sbss));
    (void)main();
    for (;;) {
    }
}

/* What a board does first on an unexpected exception: take the drive off its actuator. A board without one (the
 * qemu image, the bench) has nothing to do. */
__attribute__((weak)) void board_stop_drive(void) {}

/* Any unexpected exception (HardFault too): the actuator to zero, then stop here, where a debugger finds it; the
 * independent watchdog then resets the MCU, and a reset leaves the actuator pins as inputs (zero drive). */
void Default_Handler(void)
{
    board_stop_drive();
    for (;;) {
    }
}

typedef void (*vector_t)(void);

/* The initial stack pointer, then the handlers of exceptions 1..15 and of IRQs 0..IRQ_COUNT-1. */
typedef struct {
    void *initial_sp;
    vector_t handler[15u + IRQ_COUNT];
} vector_table_t;

#define D Default_Handler
#define D2 D, D
#define D4 D2, D2
#define D8 D4, D4
#define D16 D8, D8
#define D32 D16, D16

__attribute__((section(".isr_vector"), used)) const vector_table_t vector_table = {
    &_estack,
    {
        Reset_Handler, D2, D4, D4, D2, D, SysTick_Handler, /* exceptions 1..15 */
        D16, D,                     /* IRQ 0..16 */
        DMA1_Stream6_IRQHandler,    /* IRQ 17 */
        D16, D4,                    /* IRQ 18..37 */
        USART2_IRQHandler,          /* IRQ 38 */
        D8, D2, D,                  /* IRQ 39..49 */
        TIM5_IRQHandler,            /* IRQ 50 */
        D32, D2, D,                 /* IRQ 51..85 */
    },
};

typedef char vector_table_is_complete[(sizeof vector_table == 4u * (16u + IRQ_COUNT)) ? 1 : -1];
