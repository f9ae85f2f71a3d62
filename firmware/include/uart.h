/*
 * uart.h - UART0 to the host: interrupt-driven receive and transmit rings.
 *
 * The receive interrupt keeps taking bytes while the main loop is busy (or hung): they wait in a ring of
 * UART_RX_SIZE bytes; bytes that find it full are dropped and counted (rx_overflow), and so are the bytes
 * after them until a frame delimiter (0x00) arrives with half the ring free again, so that a host writing
 * faster than the board reads loses whole frames, not a byte here and there of every frame; bytes the hardware flags with a framing
 * error or an overrun are dropped and counted (line_errors). Frames for the host are queued whole or not at
 * all: uart_send refuses a frame that does not fit the transmit ring (counted by the caller).
 *
 * When the host's protocol runs over USB (port.c), the transmit ring is the USB link's queue instead:
 * uart_hand_over() stops UART0 (no more bytes in or out), and the USB stack drains the ring with
 * uart_tx_peek and uart_tx_consume (no second 1 KB ring in 8 KB of RAM).
 */
#ifndef UART_H
#define UART_H

#include <stdint.h>

#define UART_RX_SIZE 384u
#define UART_TX_SIZE 1024u

typedef struct {
    uint32_t rx_overflow; /* bytes lost to a full receive ring */
    uint32_t line_errors; /* bytes with a framing error or data overrun */
} uart_stats_t;

void uart_init(uint32_t baud);
/* Next received byte into *b: 1, or 0 if none waiting. */
uint8_t uart_read(uint8_t *b);
/* 1 if received bytes wait in the ring (also from an interrupt). */
uint8_t uart_rx_pending(void);
/* Queue n bytes for sending: 1, or 0 (nothing queued) if the ring has no room for all of them. */
uint8_t uart_send(const uint8_t *data, uint16_t n);
void uart_stats(uart_stats_t *out);
/* UART0 stops for good (receiver and transmitter off, both rings emptied): the transmit ring is the
 * USB link's queue from now on. */
void uart_hand_over(void);
/* Bytes queued in the transmit ring. */
uint16_t uart_tx_pending(void);
/* Room left in the transmit ring (bytes a frame may take). */
uint16_t uart_tx_free(void);
/* Once handed over (the USB link's queue, moved by the main loop only): drop the queued frames whose message
 * id is id_a or id_b (the second byte of the COBS-encoded header); the others stay, in their order. The
 * bytes at the front may be the rest of a frame whose start has already gone (to a phone that has left):
 * with `cut` NULL they stay; else they are dropped too, *cut is 1, and "01 00" takes their place (room
 * permitting), so that a receiver holding the frame's start ends it as a bad frame (a lone 00 would complete
 * a frame that lacked only its delimiter) and takes the next frame whole. The count dropped by id. */
uint8_t uart_tx_drop_frames(uint8_t id_a, uint8_t id_b, uint8_t *cut);
/* Copy up to `max` of the oldest queued bytes to dst, leaving them queued: the count copied. */
uint8_t uart_tx_peek(uint8_t *dst, uint8_t max);
/* Remove n bytes (at most those queued) from the front of the ring. */
void uart_tx_consume(uint8_t n);

#endif /* UART_H */
