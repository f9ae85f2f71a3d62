/*
 * bridge.c - UART0 of the simulated MCU <-> a pseudo-terminal the host opens like a serial port.
 *
 * Host -> board: bytes read from the pty master wait in a queue and enter the UART's receive FIFO while
 * it has room (simavr signals XOFF when full, XON when drained); the UART then delivers them to the
 * firmware at the configured baud rate, as a USB-serial adapter would. Board -> host: every byte the
 * UART transmits is written to the master; what the pty cannot take (no host reading) is dropped and
 * counted, as a UART's line would lose it. The harness keeps the slave side open itself, so a host may
 * close and reopen the path at any time without the master seeing EIO.
 *
 * Link noise (--corrupt/--drop, "noise" command) damages or loses bytes in both directions, seeded.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <pty.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <unistd.h>

#include <avr_uart.h>
#include <sim_io.h>
#include <sim_irq.h>

#include "harness.h"

static avr_irq_t *uart_input;

static uint64_t next_random(harness_t *h)
{
    /* xorshift64*: deterministic for a given --seed */
    h->rng ^= h->rng >> 12;
    h->rng ^= h->rng << 25;
    h->rng ^= h->rng >> 27;
    return h->rng * 2685821657736338717ULL;
}

static double uniform(harness_t *h) { return (double)(next_random(h) >> 11) / 9007199254740992.0; }

/* Apply link noise to one byte: returns 0 if it is lost, else 1 with *b possibly damaged. */
static int noisy(harness_t *h, uint8_t *b)
{
    if (h->drop > 0 && uniform(h) < h->drop) {
        h->dropped++;
        return 0;
    }
    if (h->corrupt > 0 && uniform(h) < h->corrupt) {
        *b ^= (uint8_t)(1 + next_random(h) % 255);
        h->corrupted++;
    }
    return 1;
}

/* One byte from the board towards the host (link noise applied); a full queue loses it. */
void bridge_transmit(harness_t *h, uint8_t b)
{
    if (!noisy(h, &b))
        return;
    if (h->txq_len == sizeof h->txq) {
        h->dropped_out++;
        return;
    }
    h->txq[h->txq_len++] = b;
}

static void on_uart_output(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    harness_t *h = param;
    if (!h->max) /* --usb: UART0 is not wired to the pty */
        bridge_transmit(h, (uint8_t)value);
}

static void on_xon(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)value;
    ((harness_t *)param)->uart_xoff = 0;
}

static void on_xoff(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    ((harness_t *)param)->uart_xoff = value != 0;
}

int bridge_open(harness_t *h, const char *link)
{
    char name[256];
    if (openpty(&h->master, &h->slave, name, NULL, NULL) < 0) {
        perror("avr-harness: openpty");
        return -1;
    }
    struct termios tio;
    tcgetattr(h->slave, &tio);
    cfmakeraw(&tio);
    tcsetattr(h->slave, TCSANOW, &tio);
    fcntl(h->master, F_SETFL, fcntl(h->master, F_GETFL) | O_NONBLOCK);
    if (link) {
        char tmp[4096];
        snprintf(tmp, sizeof tmp, "%s.%d.tmp", link, (int)getpid());
        unlink(tmp);
        if (symlink(name, tmp) < 0 || rename(tmp, link) < 0) {
            fprintf(stderr, "avr-harness: cannot link %s -> %s: %s\n", link, name, strerror(errno));
            return -1;
        }
    }
    dprintf(h->out_fd, "%s\n", name);
    return 0;
}

void bridge_attach(harness_t *h)
{
    uint32_t flags = 0; /* no console echo of UART lines, no polling sleeps */
    avr_ioctl(h->avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    uart_input = avr_io_getirq(h->avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(h->avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT),
                            on_uart_output, h);
    avr_irq_register_notify(avr_io_getirq(h->avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON), on_xon, h);
    avr_irq_register_notify(avr_io_getirq(h->avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF), on_xoff, h);
}

/* 1 when byte b ends a wire frame (a 0x00 after at least one other byte; idle 0x00 fill counts nothing),
 * for the link statistics every far-side server reports (firmware_sim/servers/base.py). */
static int count_frame(int *open, uint8_t b)
{
    int ended = b == 0 && *open;
    *open = b != 0;
    return ended;
}

/* One byte from the host into the receive queue (link noise applied); a full queue loses it. */
void bridge_receive(harness_t *h, uint8_t b)
{
    h->bytes_in++;
    h->frames_in += count_frame(&h->frame_open_in, b);
    if (h->rxq_tail - h->rxq_head == (uint32_t)sizeof h->rxq)
        h->dropped++;
    else if (noisy(h, &b))
        h->rxq[h->rxq_tail++ % sizeof h->rxq] = b;
}

void bridge_service(harness_t *h)
{
    /* host -> queue (--uart-pipe: the "rx" command fills it instead) */
    uint32_t room = h->uart_pipe ? 0 : (uint32_t)sizeof h->rxq - (h->rxq_tail - h->rxq_head);
    while (room > 0) {
        uint8_t buf[4096];
        ssize_t n = read(h->master, buf, room < sizeof buf ? room : sizeof buf);
        if (n <= 0)
            break; /* EAGAIN: nothing waiting; EIO cannot happen while we hold the slave */
        h->bytes_in += (uint64_t)n;
        for (ssize_t i = 0; i < n; i++) {
            uint8_t b = buf[i];
            h->frames_in += count_frame(&h->frame_open_in, b);
            if (noisy(h, &b))
                h->rxq[h->rxq_tail++ % sizeof h->rxq] = b;
        }
        room = (uint32_t)sizeof h->rxq - (h->rxq_tail - h->rxq_head);
    }
    /* queue -> UART receive FIFO, while it has room (--usb: the phone app's writes); nothing enters an MCU
     * held in reset (the phone's buffer is the phone's: it keeps them) */
    if (h->max)
        usb_service(h);
    while (!h->max && !h->held && !h->uart_xoff && h->rxq_head != h->rxq_tail)
        avr_raise_irq(uart_input, h->rxq[h->rxq_head++ % sizeof h->rxq]);
    if (h->held && !h->max)
        h->rxq_head = h->rxq_tail;
    /* UART -> host (--uart-pipe: the "step" answer takes them) */
    if (h->txq_len && !h->uart_pipe) {
        ssize_t n = write(h->master, h->txq, h->txq_len);
        if (n > 0) {
            h->bytes_out += (uint64_t)n;
            for (ssize_t i = 0; i < n; i++)
                h->frames_out += count_frame(&h->frame_open_out, h->txq[i]);
            memmove(h->txq, h->txq + n, h->txq_len - (uint32_t)n);
            h->txq_len -= (uint32_t)n;
        } else if (n < 0 && errno != EAGAIN) {
            h->dropped_out += h->txq_len;
            h->txq_len = 0;
        }
    }
}

void bridge_close(harness_t *h, const char *link)
{
    if (link) {
        char target[4096];
        ssize_t n = readlink(link, target, sizeof target - 1);
        if (n > 0) {
            target[n] = 0;
            if (strcmp(target, ttyname(h->slave) ? ttyname(h->slave) : "") == 0)
                unlink(link);
        }
    }
    close(h->master);
    close(h->slave);
}
