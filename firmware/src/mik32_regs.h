/* MIK32 "Amur" register addresses and bit positions used by this firmware.
 *
 * Facts (addresses, offsets, bit positions) taken from the vendor's public SDK headers
 * (MikronMIK32/mik32v2-shared: include/mik32_memory_map.h, periphery/uart.h, spi.h, gpio.h,
 * timer32.h, power_manager.h, wdt.h, epic.h); written here in this project's own form.
 * docs/firmware.md lists which fact comes from which header and what is assumed. */
#ifndef MIK32_REGS_H
#define MIK32_REGS_H
#include <stdint.h>

#define REG32(addr) (*(volatile uint32_t *)(uintptr_t)(addr))

/* memory map (mik32_memory_map.h) */
#define MIK_RAM_BASE        0x02000000u
#define MIK_RAM_SIZE        (16u * 1024u)
#define MIK_SPIFI_BASE      0x80000000u

#define MIK_PM_BASE         0x00050000u
#define MIK_EPIC_BASE       0x00050400u
#define MIK_WDT_BASE        0x00081000u
#define MIK_UART0_BASE      0x00081400u
#define MIK_TIMER32_1_BASE  0x00082800u
#define MIK_SPI0_BASE       0x00083000u
#define MIK_GPIO0_BASE      0x00084000u
#define MIK_GPIO1_BASE      0x00084400u
#define MIK_PAD_CONFIG_BASE 0x00050C00u

/* power manager: clock gating (power_manager.h offsets, mik32_memory_map.h bits) */
#define PM_CLK_APB_M_SET    (MIK_PM_BASE + 0x14u)
#define PM_CLK_APB_P_SET    (MIK_PM_BASE + 0x1Cu)
#define PM_WDT_CLK_MUX      (MIK_PM_BASE + 0x28u)
#define PM_WDT_CLK_LSI32K   3u            /* 0 OSC32M, 1 HSI32M, 2 OSC32K, 3 LSI32K */
#define PM_APB_M_EPIC       (1u << 1)
#define PM_APB_M_PAD_CONFIG (1u << 3)
#define PM_APB_P_WDT        (1u << 0)
#define PM_APB_P_UART0      (1u << 1)
#define PM_APB_P_TIMER32_1  (1u << 6)
#define PM_APB_P_SPI0       (1u << 8)
#define PM_APB_P_GPIO0      (1u << 12)
#define PM_APB_P_GPIO1      (1u << 13)

/* pad configuration (pad_config.h: per port CFG, DS, PUPD at 0x0C steps, 2 bits a pin;
 * MIK32V2 modes from the vendor HAL: 00 GPIO, 01 first function (SPI0/UART0 pins below),
 * 10 second function / timer, 11 analog). Pins (HAL pin map): port 0 pin 0 SPI0_MISO,
 * 1 SPI0_MOSI, 2 SPI0_CLK, 3 SPI0_N_SS_IN, 4 SPI0_N_SS_OUT_0, 5 UART0_RXD, 6 UART0_TXD,
 * 11-15 JTAG (TDI, TCK, TMS, TRST, TDO) - left as they are. */
#define PAD_PORT0_CFG       (MIK_PAD_CONFIG_BASE + 0x00u)
#define PAD_PORT1_CFG       (MIK_PAD_CONFIG_BASE + 0x0Cu)
#define PAD_MODE_GPIO       0u
#define PAD_MODE_FUNC1      1u
#define PAD_FIELD(pin, mode) ((uint32_t)(mode) << (2u * (pin)))

/* UART (uart.h): CONTROL1 0x00, CONTROL2 0x04, CONTROL3 0x08, DIVIDER 0x0C, FLAGS 0x1C,
 * RXDATA 0x24, TXDATA 0x28 */
#define UART_CONTROL1       0x00u
#define UART_DIVIDER        0x0Cu
#define UART_FLAGS          0x1Cu
#define UART_RXDATA         0x24u
#define UART_TXDATA         0x28u
#define UART_CONTROL1_UE    (1u << 0)
#define UART_CONTROL1_RE    (1u << 2)
#define UART_CONTROL1_TE    (1u << 3)
#define UART_FLAGS_ORE      (1u << 3)
#define UART_FLAGS_RXNE     (1u << 5)
#define UART_FLAGS_TC       (1u << 6)
#define UART_FLAGS_TXE      (1u << 7)

/* SPI (spi.h): CONFIG 0x00, INT_STATUS 0x04, ENABLE 0x14, DELAY 0x18, TXDATA 0x1C,
 * RXDATA 0x20, TX_THR 0x28 */
#define SPI_CONFIG          0x00u
#define SPI_INT_STATUS      0x04u
#define SPI_ENABLE          0x14u
#define SPI_DELAY           0x18u
#define SPI_TXDATA          0x1Cu
#define SPI_RXDATA          0x20u
#define SPI_CONFIG_MASTER   (1u << 0)
#define SPI_CONFIG_CLK_PH   (1u << 2)
#define SPI_CONFIG_DIV_S    3u            /* baud divider 2^(v+1), v = 0..7 */
#define SPI_CONFIG_CS_NONE  (0xFu << 10)
#define SPI_CONFIG_MANUAL_CS (1u << 14)
#define SPI_ENABLE_EN       (1u << 0)
#define SPI_ENABLE_CLR_TX   (1u << 2)
#define SPI_ENABLE_CLR_RX   (1u << 3)
#define SPI_ST_RX_OVERFLOW  (1u << 0)
#define SPI_ST_TX_NOT_FULL  (1u << 2)
#define SPI_ST_RX_NOT_EMPTY (1u << 4)
#define SPI_ST_ACTIVE       (1u << 15)

/* GPIO (gpio.h): SET/STATE 0x00, CLEAR 0x04, DIRECTION_OUT 0x08, DIRECTION_IN 0x0C,
 * OUTPUT 0x10 */
#define GPIO_SET            0x00u
#define GPIO_CLEAR          0x04u
#define GPIO_DIR_OUT        0x08u
#define GPIO_OUTPUT         0x10u

/* TIMER32 (timer32.h): VALUE 0x00, TOP 0x04, PRESCALER 0x08, CONTROL 0x0C, ENABLE 0x10,
 * INT_MASK 0x14, INT_CLEAR 0x18, INT_FLAGS 0x1C; channel k at 0x80 + 0x10 k: CNTRL, OCR */
#define TIM_VALUE           0x00u
#define TIM_TOP             0x04u
#define TIM_PRESCALER       0x08u
#define TIM_CONTROL         0x0Cu
#define TIM_ENABLE          0x10u
#define TIM_INT_MASK        0x14u
#define TIM_INT_CLEAR       0x18u
#define TIM_INT_FLAGS       0x1Cu
#define TIM_CH0_CNTRL       0x80u
#define TIM_CH0_OCR         0x84u
#define TIM_ENABLE_EN       (1u << 0)
#define TIM_ENABLE_CLR      (1u << 1)
#define TIM_CH_MODE_COMPARE (1u << 5)
#define TIM_CH_ENABLE       (1u << 7)
#define TIM_INT_OC0         (1u << 6)

/* watchdog (wdt.h, mik32_hal_wdt): CON 0x84 (PRELOAD 0-11, PRESCALE 12-14: 1, 2, 4, 16, 64,
 * 256, 1024, 4096), KEY (byte) / STA 0x9C (ENABLED 0, LOADING 1, RST_FLAG 8); a CON write or a
 * key must follow the unlock key; the counter runs from PRELOAD up to 4095 and resets the MCU */
#define WDT_CON             0x84u
#define WDT_KEY             0x9Cu
#define WDT_STA             0x9Cu
#define WDT_KEY_UNLOCK      0x1Eu
#define WDT_KEY_START       0x71u
#define WDT_KEY_STOP        0xE8u
#define WDT_CON_PRESCALE_S  12u
#define WDT_PRESCALE_64     4u
#define WDT_STA_RST_FLAG    (1u << 8)

#endif
