/*
 * codec_check.c - the firmware's codec alone on the ATmega2560, for checking it against the protocol's
 * test vectors under simavr (tests/test_firmware_codec.py). Not flashed to boards.
 *
 * Every byte from UART0 goes through the same deframer the board uses. For each event it answers on UART0:
 *   a valid frame  -> that frame re-encoded from the decoded message (so decode and encode are both checked:
 *                     a canonical vector must come back byte for byte)
 *   a bad frame    -> COBS([0xBA, reason, field, element]) + 0x00, reason a BAD_FRAME_* code
 * Polled UART at 115200 baud, no interrupts: the simplest thing that exercises the codec.
 */
#include <avr/io.h>
#include <string.h>

#include "cobs.h"
#include "frame.h"

#define BAUD_UBRR 16u /* 115200 baud with U2X at 16 MHz (-2.1 %), as the board firmware */

static deframer_t deframer;
static frame_t frame;
static uint8_t wire[FRAME_MAX_WIRE];

static void uart_put(uint8_t c)
{
    while (!(UCSR0A & _BV(UDRE0)))
        ;
    UDR0 = c;
}

static void send_bytes(const uint8_t *p, uint16_t n)
{
    while (n--)
        uart_put(*p++);
}

static void send_cobs(const uint8_t *raw, uint16_t n)
{
    uint16_t len = cobs_encode(raw, n, wire);
    wire[len] = 0;
    send_bytes(wire, (uint16_t)(len + 1));
}

int main(void)
{
    UCSR0A = _BV(U2X0);
    UBRR0 = BAUD_UBRR;
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);
    UCSR0B = _BV(RXEN0) | _BV(TXEN0);
    deframer_init(&deframer);
    for (;;) {
        while (!(UCSR0A & _BV(RXC0)))
            ;
        uint8_t byte = UDR0;
        switch (deframer_feed(&deframer, byte, &frame)) {
        case DEFRAME_FRAME: {
            uint16_t n = frame_encode(frame.msg_id, frame.seq, frame.flags, &frame.msg, wire);
            if (n) {
                send_bytes(wire, n);
            } else {
                uint8_t raw[2] = {0xEE, frame.msg_id};
                send_cobs(raw, 2);
            }
            break;
        }
        case DEFRAME_BAD: {
            uint8_t raw[4] = {0xBA, deframer.last_bad, deframer.last_where.field,
                              deframer.last_where.element};
            send_cobs(raw, 4);
            break;
        }
        default:
            break;
        }
    }
}
