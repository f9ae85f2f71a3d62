/* port.c - the byte link to the host: UART0, USB (AOA) or the first to speak (see port.h). */
#include "port.h"

#include <avr/pgmspace.h>

#include "aoa.h"
#include "app.h"
#include "clock.h"
#include "spi.h"
#include "uart.h"

static struct {
    uint8_t mode;     /* LINK_UART, LINK_USB or LINK_FIRST as configured */
    uint8_t active;   /* the link chosen (LINK_FIRST: not yet) */
    uint8_t source;   /* with LINK_FIRST: LINK_UART or LINK_USB, the link bytes are read from now */
    uint8_t boundary; /* the last byte read from `source` ended a frame (or none was read) */
    uint16_t last_byte_ms; /* low 16 bits of clock_ms(): only differences under PORT_SWITCH_MS matter */
} port;

void port_init(const board_config_t *cfg)
{
    port.mode = port.active = cfg->link;
    port.source = LINK_UART;
    port.boundary = 1;
    if (cfg->link != LINK_USB)
        uart_init(cfg->baud);
    else
        uart_hand_over(); /* UART0 stays off; its transmit ring is the USB link's queue */
    if (cfg->link != LINK_UART)
        aoa_init(cfg->serial);
}

uint8_t port_active(void) { return port.active; }

static uint8_t usb_bytes(void) { return port.mode != LINK_UART && aoa_rx_pending(); }

void port_poll(void)
{
    if (port.mode != LINK_UART && port.active != LINK_UART) /* "first" won by UART0: USB rests */
        aoa_poll(usb_now_us());
}

static uint8_t read_from(uint8_t source, uint8_t *b)
{
    return source == LINK_USB ? aoa_read(b) : uart_read(b);
}

uint8_t port_read(uint8_t *b)
{
    if (port.active != LINK_FIRST)
        return read_from(port.active, b);
    uint16_t now = (uint16_t)clock_ms();
    if (!read_from(port.source, b)) {
        uint8_t other = port.source == LINK_UART ? LINK_USB : LINK_UART;
        uint8_t waiting = other == LINK_USB ? usb_bytes() : uart_rx_pending();
        if (!waiting || (!port.boundary && (uint16_t)(now - port.last_byte_ms) < PORT_SWITCH_MS))
            return 0;
        port.source = other; /* at a frame boundary, or the source went silent in a frame */
        if (!read_from(port.source, b))
            return 0;
    }
    port.boundary = *b == 0x00;
    port.last_byte_ms = now;
    return 1;
}

uint8_t port_rx_pending(void)
{
    if (port.active == LINK_UART)
        return uart_rx_pending();
    if (port.active == LINK_USB)
        return aoa_rx_pending();
    return uart_rx_pending() || usb_bytes();
}

uint8_t port_send(const uint8_t *data, uint16_t n)
{
    return uart_send(data, n); /* the ring goes to TXD, or (USB) to the bulk OUT pipe */
}

void port_frame_valid(void)
{
    if (port.active != LINK_FIRST)
        return;
    port.active = port.source;
    if (port.active == LINK_USB)
        uart_hand_over(); /* UART0 is silent from now on: no "bytes lost" reports for a port nobody reads */
}

/* ------------------------------------------------------------------ the USB stack's side (aoa.h) */
uint16_t usb_tx_pending(void) { return port.active == LINK_USB ? uart_tx_pending() : 0; }

uint8_t usb_tx_peek(uint8_t *dst, uint8_t max) { return uart_tx_peek(dst, max); }

void usb_tx_consume(uint8_t n) { uart_tx_consume(n); }

void usb_link_event(uint8_t ev, uint16_t arg)
{
    char text[72];
    aoa_event_text(ev, arg, text, sizeof text);
    uint8_t refused = ev == AOA_EV_NO_AOA || ev == AOA_EV_FAILED || ev == AOA_EV_NO_PIPES;
    uint8_t severity = refused ? SEVERITY_ERROR : (ev == AOA_EV_DOWN ? SEVERITY_WARNING : SEVERITY_INFO);
    report_log(severity, refused ? LOG_CODE_HANDSHAKE : LOG_CODE_STATE, PSTR("%s"), text);
}
