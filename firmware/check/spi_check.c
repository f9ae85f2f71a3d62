/*
 * spi_check.c - the harness's USB wiring (harness/usb.c) seen from the ATmega2560, for
 * tests/test_max3421e_harness.py. Not flashed to boards, and independent of the firmware's USB stack: its
 * own few lines of SPI, so a wiring fault and a stack fault cannot hide each other.
 *
 * It talks to the MAX3421E on the Mega ADK's pins (board_pins.h) once, records what it saw in `check`
 * (the test reads it with the harness's "mem" command at the symbol's address), then idles:
 * REVISION before and after PINCTL.FDUPSPI, the oscillator after CHIPRES, a bus reset whose BUSEVENTIRQ
 * must pull the INT pin (PE6) low and release it when cleared, a GET_DESCRIPTOR(device) control transfer
 * by hand, and REVISION while RES (PJ2) holds the chip in reset.
 */
#include <avr/io.h>
#include <stdint.h>

#include "board_pins.h"

#define R_RCVFIFO 1
#define R_SUDFIFO 4
#define R_RCVBC 6
#define R_USBIRQ 13
#define R_USBCTL 15
#define R_CPUCTL 16
#define R_PINCTL 17
#define R_REVISION 18
#define R_HIRQ 25
#define R_HIEN 26
#define R_MODE 27
#define R_PERADDR 28
#define R_HCTL 29
#define R_HXFR 30
#define R_HRSL 31

struct check {
    uint8_t done;          /* 0xA5 when every step ran */
    uint8_t rev_half;      /* REVISION read before FDUPSPI: 0xFF (MISO unused) */
    uint8_t rev;           /* after: 0x13 */
    uint8_t osc_ok;        /* OSCOKIRQ came after CHIPRES */
    uint8_t int_low;       /* INT went low on BUSEVENTIRQ (enabled) */
    uint8_t int_high;      /* ... and high again once it was cleared */
    uint8_t setup_hrsl;    /* HRSL result of the SETUP */
    uint8_t in_hrsl;       /* ... of the IN data packet */
    uint8_t status_hrsl;   /* ... of the HS-OUT status stage */
    uint8_t rcvbc;         /* bytes in the data packet */
    uint8_t desc[18];      /* the device descriptor */
    uint8_t rev_in_reset;  /* REVISION while RES is low: 0xFF, nobody answers */
    uint8_t rev_after_res; /* after RES: 0xFF again, PINCTL was reset too */
    uint16_t polls;        /* HIRQ polls waiting for the SETUP's HXFRDNIRQ (the transfer takes time) */
};

volatile struct check check;

static uint8_t spi(uint8_t b)
{
    SPDR = b;
    while (!(SPSR & _BV(SPIF)))
        ;
    return SPDR;
}

static void select(uint8_t on)
{
    if (on)
        PORTB &= (uint8_t)~_BV(USB_SS_PIN_BIT);
    else
        PORTB |= _BV(USB_SS_PIN_BIT);
}

static void wr(uint8_t reg, uint8_t v)
{
    select(1);
    spi((uint8_t)(reg << 3 | 2));
    spi(v);
    select(0);
}

static uint8_t rd(uint8_t reg)
{
    select(1);
    spi((uint8_t)(reg << 3));
    uint8_t v = spi(0);
    select(0);
    return v;
}

static uint16_t wait_bit(uint8_t reg, uint8_t bit)
{
    uint16_t n = 0;
    while (!(rd(reg) & bit) && n < 60000u)
        n++;
    return n;
}

static uint8_t xfer(uint8_t token)
{
    wr(R_HXFR, token);
    wait_bit(R_HIRQ, 0x80);
    wr(R_HIRQ, 0x80);
    return rd(R_HRSL) & 0x0F;
}

int main(void)
{
    PORTB |= _BV(USB_SS_PIN_BIT);
    DDRB |= _BV(USB_SS_PIN_BIT) | _BV(USB_SCK_PIN_BIT) | _BV(USB_MOSI_PIN_BIT);
    PORTE |= _BV(USB_INT_PIN_BIT);
    PORTJ |= _BV(USB_RES_PIN_BIT);
    DDRJ |= _BV(USB_RES_PIN_BIT);
    SPCR = _BV(SPE) | _BV(MSTR);
    SPSR = _BV(SPI2X);

    check.rev_half = rd(R_REVISION);
    wr(R_PINCTL, 0x18); /* FDUPSPI | INTLEVEL */
    check.rev = rd(R_REVISION);
    wr(R_USBCTL, 0x20); /* CHIPRES */
    wr(R_USBCTL, 0);
    check.osc_ok = wait_bit(R_USBIRQ, 0x01) < 60000u;

    wr(R_MODE, 0xC9); /* DPPULLDN | DMPULLDN | SOFKAENAB | HOST */
    wr(R_HIRQ, 0xFF);
    wr(R_HIEN, 0x01); /* BUSEVENTIE */
    wr(R_CPUCTL, 0x01);
    wr(R_HCTL, 0x01); /* BUSRST: 50 ms */
    for (uint32_t n = 0; n < 2000000ul && !check.int_low; n++)
        check.int_low = !(PINE & _BV(USB_INT_PIN_BIT));
    wr(R_HIRQ, 0x01);
    check.int_high = (PINE & _BV(USB_INT_PIN_BIT)) != 0;
    wr(R_HIEN, 0);

    static const uint8_t get_device[8] = {0x80, 6, 0, 1, 0, 0, 18, 0};
    wr(R_PERADDR, 0);
    select(1);
    spi(R_SUDFIFO << 3 | 2);
    for (uint8_t i = 0; i < 8; i++)
        spi(get_device[i]);
    select(0);
    wr(R_HXFR, 0x10);
    check.polls = wait_bit(R_HIRQ, 0x80);
    wr(R_HIRQ, 0x80);
    check.setup_hrsl = rd(R_HRSL) & 0x0F;
    wr(R_HCTL, 0x20); /* RCVTOG1 */
    check.in_hrsl = xfer(0x00);
    check.rcvbc = rd(R_RCVBC);
    select(1);
    spi(R_RCVFIFO << 3);
    for (uint8_t i = 0; i < 18 && i < check.rcvbc; i++)
        check.desc[i] = spi(0);
    select(0);
    wr(R_HIRQ, 0x04); /* RCVDAVIRQ: free the buffer */
    check.status_hrsl = xfer(0xA0);

    PORTJ &= (uint8_t)~_BV(USB_RES_PIN_BIT);
    check.rev_in_reset = rd(R_REVISION);
    PORTJ |= _BV(USB_RES_PIN_BIT);
    check.rev_after_res = rd(R_REVISION);
    check.done = 0xA5;
    for (;;)
        ;
}
