"""A register-level model of the STM32F401 board running the flashed image (``hil-mock --firmware board``).

``mcu.Stm32f401`` runs ``furuta_fw.elf`` — the very image ``scripts/build_firmware`` makes for the board — on
unicorn's Cortex-M4 (Thumb-2 code, memory callbacks for the peripherals) with models of the peripherals board.c
uses (``peripherals``); ``device.BoardFirmware`` puts it behind hil_mock's device loop with the plant simulator
driving the encoder and the ADC and the PWM duty and direction driving the plant.
"""
