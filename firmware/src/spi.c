/* spi.c - the ATmega2560's SPI master and the MAX3421E's INT/RES lines on the Mega ADK (see spi.h). */
#include "spi.h"

#include <avr/io.h>

#include "board_pins.h"
#include "clock.h"

void spi_init(void)
{
    PORTB |= _BV(USB_SS_PIN_BIT); /* deselected before it becomes an output: no stray command */
    DDRB |= _BV(USB_SS_PIN_BIT) | _BV(USB_SCK_PIN_BIT) | _BV(USB_MOSI_PIN_BIT);
    DDRB &= (uint8_t)~_BV(USB_MISO_PIN_BIT);
    DDRE &= (uint8_t)~_BV(USB_INT_PIN_BIT);
    PORTE |= _BV(USB_INT_PIN_BIT); /* INT is open-drain on the chip */
    PORTJ |= _BV(USB_RES_PIN_BIT);
    DDRJ |= _BV(USB_RES_PIN_BIT); /* RES high: the chip runs */
    SPCR = _BV(SPE) | _BV(MSTR);   /* master, mode 0, MSB first */
    SPSR = _BV(SPI2X);             /* fosc/2 = 8 MHz */
}

void spi_select(uint8_t on)
{
    if (on)
        PORTB &= (uint8_t)~_BV(USB_SS_PIN_BIT);
    else
        PORTB |= _BV(USB_SS_PIN_BIT);
}

uint8_t spi_byte(uint8_t out)
{
    SPDR = out;
    while (!(SPSR & _BV(SPIF))) /* 16 CPU cycles at fosc/2: bounded by the hardware */
        ;
    return SPDR;
}

uint8_t usb_int_asserted(void) { return !(PINE & _BV(USB_INT_PIN_BIT)); }

void usb_reset_pin(uint8_t low)
{
    if (low)
        PORTJ &= (uint8_t)~_BV(USB_RES_PIN_BIT);
    else
        PORTJ |= _BV(USB_RES_PIN_BIT);
}

uint32_t usb_now_us(void) { return clock_us(); }
