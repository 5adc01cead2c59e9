"""Board emulator: MCU firmware behaviour, SPI peripherals, virtual clock, serial server."""
