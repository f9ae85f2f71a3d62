/* uart.c - UART0 rings (see uart.h). */
#include "uart.h"

#include <avr/interrupt.h>
#include <avr/io.h>
#include <util/atomic.h>

#include "config.h"

static volatile uint8_t rx_buf[UART_RX_SIZE];
static volatile uint16_t rx_head, rx_tail; /* head: next write (ISR), tail: next read (main loop) */
static volatile uint8_t tx_buf[UART_TX_SIZE];
static volatile uint16_t tx_head, tx_tail;
static volatile uart_stats_t stats;
static volatile uint8_t flags;
#define HANDED_OVER 0x01u /* the transmit ring is the USB link's queue (port.c), not UART0's */
#define RX_RESYNC 0x02u   /* the receive ring overflowed: drop bytes up to the next frame delimiter */

/* The receive ring's next index. A compare, not `% UART_RX_SIZE`: the size is no power of two, and the
 * 16-bit division that took (~200 cycles) ran twice a received byte, in the interrupt and in the read. */
static inline uint16_t rx_next(uint16_t at) { return at + 1u == UART_RX_SIZE ? 0u : (uint16_t)(at + 1u); }

void uart_init(uint32_t baud)
{
    /* Double speed: UBRR = F_CPU / (8 baud) - 1, rounded (115200 -> 16, +2.1 %; 250000/500000/1M exact);
     * config.c refuses a rate this makes too far off. */
    uint16_t ubrr = (uint16_t)(config_uart_divisor(baud) - 1u);
    UCSR0A = _BV(U2X0);
    UBRR0 = ubrr;
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00); /* 8N1 */
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
}

ISR(USART0_RX_vect)
{
    uint8_t status = UCSR0A;
    uint8_t b = UDR0;
    if (status & (_BV(FE0) | _BV(DOR0))) {
        stats.line_errors++;
        return;
    }
    uint16_t next = rx_next(rx_head);
    if (next == rx_tail) {
        stats.rx_overflow++;
        flags |= RX_RESYNC;
        return;
    }
    if (flags & RX_RESYNC) {
        /* After an overflow, bytes go in again only from a frame delimiter on, and only once the main loop
         * has read half the ring: a frame is then taken whole or not at all, where taking a byte each time
         * one is read would cut every frame of a flood. The delimiter ends the cut frame in the ring. */
        if (b != 0x00 || (uint16_t)((rx_tail + UART_RX_SIZE - next) % UART_RX_SIZE) < UART_RX_SIZE / 2u) {
            stats.rx_overflow++;
            return;
        }
        flags &= (uint8_t)~RX_RESYNC;
    }
    rx_buf[rx_head] = b;
    rx_head = next;
}

ISR(USART0_UDRE_vect)
{
    if (tx_tail == tx_head) {
        UCSR0B &= (uint8_t)~_BV(UDRIE0);
        return;
    }
    UDR0 = tx_buf[tx_tail];
    tx_tail = (uint16_t)((tx_tail + 1u) % UART_TX_SIZE);
}

uint8_t uart_read(uint8_t *b)
{
    uint16_t head;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { head = rx_head; }
    if (rx_tail == head)
        return 0;
    *b = rx_buf[rx_tail];
    uint16_t next = rx_next(rx_tail);
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { rx_tail = next; }
    return 1;
}

uint8_t uart_rx_pending(void)
{
    uint8_t pending;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { pending = rx_head != rx_tail; }
    return pending;
}

uint8_t uart_send(const uint8_t *data, uint16_t n)
{
    uint16_t tail;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { tail = tx_tail; }
    uint16_t used = (uint16_t)((tx_head + UART_TX_SIZE - tail) % UART_TX_SIZE);
    if ((uint32_t)used + n >= UART_TX_SIZE)
        return 0;
    uint16_t head = tx_head;
    for (uint16_t i = 0; i < n; i++) {
        tx_buf[head] = data[i];
        head = (uint16_t)((head + 1u) % UART_TX_SIZE);
    }
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        tx_head = head;
        if (!(flags & HANDED_OVER))
            UCSR0B |= _BV(UDRIE0);
    }
    return 1;
}

void uart_stats(uart_stats_t *out)
{
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        out->rx_overflow = stats.rx_overflow;
        out->line_errors = stats.line_errors;
    }
}

void uart_hand_over(void)
{
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        flags = HANDED_OVER;
        UCSR0B = 0;        /* receiver, transmitter and their interrupts off: the pins are plain inputs */
        tx_tail = tx_head; /* half-sent UART frames must not continue on the other link */
        rx_tail = rx_head; /* nor UART bytes reach the deframer */
    }
}

uint16_t uart_tx_pending(void)
{
    uint16_t tail;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { tail = tx_tail; }
    return (uint16_t)((tx_head + UART_TX_SIZE - tail) % UART_TX_SIZE);
}

uint16_t uart_tx_free(void) { return (uint16_t)(UART_TX_SIZE - 1u - uart_tx_pending()); }

static uint16_t tx_next(uint16_t at) { return at + 1u == UART_TX_SIZE ? 0u : (uint16_t)(at + 1u); }

uint8_t uart_tx_drop_frames(uint8_t id_a, uint8_t id_b, uint8_t *cut)
{
    /* Compacted in place towards the tail: the write position never passes the read position. */
    uint16_t head = tx_head, r = tx_tail, w = tx_tail;
    /* a frame starts at the tail when the byte before it (sent, or never written: 0) is a delimiter */
    uint8_t inside = tx_buf[r ? r - 1u : UART_TX_SIZE - 1u] != 0x00;
    uint8_t dropped = 0, was_cut = 0;
    while (r != head) {
        uint8_t drop;
        if (inside) {
            inside = 0;
            drop = was_cut = cut != 0;
        } else {
            /* COBS: a first code byte >= 3 is followed by the header's version and message id unchanged */
            uint16_t at = tx_next(r);
            drop = tx_buf[r] >= 3u && (tx_buf[tx_next(at)] == id_a || tx_buf[tx_next(at)] == id_b);
            dropped += drop;
        }
        uint8_t b;
        do {
            b = tx_buf[r];
            r = tx_next(r);
            if (!drop) {
                tx_buf[w] = b;
                w = tx_next(w);
            }
        } while (b != 0x00 && r != head);
    }
    uint16_t tail = tx_tail;
    if (was_cut) {
        *cut = 1;
        if ((uint16_t)((w + UART_TX_SIZE - tail) % UART_TX_SIZE) + 3u < UART_TX_SIZE) {
            tail = tail >= 2u ? (uint16_t)(tail - 2u) : (uint16_t)(tail + UART_TX_SIZE - 2u);
            tx_buf[tail] = 0x01;
            tx_buf[tx_next(tail)] = 0x00;
            tx_buf[tail ? tail - 1u : UART_TX_SIZE - 1u] = 0x00; /* free space: "01 00" starts a chunk */
        }
    } else if (cut) {
        *cut = 0;
    }
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        tx_head = w;
        tx_tail = tail;
    }
    return dropped;
}

uint8_t uart_tx_peek(uint8_t *dst, uint8_t max)
{
    uint16_t n = uart_tx_pending();
    if (n > max)
        n = max;
    uint16_t at = tx_tail;
    for (uint16_t i = 0; i < n; i++) {
        dst[i] = tx_buf[at];
        at = (uint16_t)((at + 1u) % UART_TX_SIZE);
    }
    return (uint8_t)n;
}

void uart_tx_consume(uint8_t n)
{
    uint16_t pending = uart_tx_pending();
    if (n > pending)
        n = (uint8_t)pending;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { tx_tail = (uint16_t)((tx_tail + n) % UART_TX_SIZE); }
}
