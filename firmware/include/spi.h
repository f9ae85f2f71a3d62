/*
 * spi.h - the USB host stack's only contact with hardware: the MAX3421E's chip select and SPI bytes, its
 * INT and RES lines, and a microsecond clock for the stack's timeouts.
 *
 * src/spi.c implements it on the ATmega2560 (wiring in board_pins.h); check/usb_check.c implements it
 * on the host against the chip model (harness/max3421e.c), so max3421e.c, usb_host.c and aoa.c run
 * unchanged in both.
 */
#ifndef SPI_H
#define SPI_H

#include <stdint.h>

/* SS, SCK, MOSI outputs (SS high), MISO input, INT input with pull-up, RES an output held high (chip
 * running); SPI master, mode 0, MSB first, fosc/2 (8 MHz: one byte in ~1 us). */
void spi_init(void);
/* 1: drive SS low (a MAX3421E command starts); 0: release it (the command ends). */
void spi_select(uint8_t on);
/* One full-duplex byte while selected: send `out`, return what the chip sent back. */
uint8_t spi_byte(uint8_t out);
/* The chip's INT line is asserted (level mode, active low on the pin). */
uint8_t usb_int_asserted(void);
/* Hold the chip's RES line low (1) or release it (0): a hard chip reset. */
void usb_reset_pin(uint8_t low);
/* Microseconds since reset, wrapping after 71.6 minutes (compare differences, never absolute values). */
uint32_t usb_now_us(void);

#endif /* SPI_H */
