/*
 * harness.h - runs the board firmware on simavr's ATmega2560 behind a pseudo-terminal.
 *
 * One thread, one loop: run the MCU for a slice of simulated time, move bytes between the pty and
 * UART0, update the analog inputs from the power model, apply scheduled faults, answer control commands,
 * then (paced mode) wait until wall time catches up with simulated time. Time is the MCU's cycle count
 * plus the cycles it spent held in reset by a brown-out, so it runs on through resets.
 *
 * Parts: bridge.c (pty <-> UART0, link noise), power.c (battery, UBEC rail, ADC inputs, brown-out),
 * record.c (pulse edges and resets to a file), ocr.c (the timers' double-buffered compare registers,
 * which simavr lacks), control.c (commands on stdin), main.c (options, loop), usb.c (--usb: the USB host
 * port, a MAX3421E with a phone plugged in, max3421e.c; the pty is then the phone's accessory app).
 */
#ifndef HARNESS_H
#define HARNESS_H

#include <stdint.h>
#include <stdio.h>

#include <sim_avr.h>

#define MAX_SAGS 16
#define MAX_HANGS 16

/* Reset causes as recorded (the protocol's ResetCause values). */
enum { CAUSE_POWER_ON = 0, CAUSE_WATCHDOG = 1, CAUSE_BROWN_OUT = 2, CAUSE_EXTERNAL = 3 };

typedef struct {
    double start_s, drop_v, ramp_s, duration_s;
} sag_t;

typedef struct {
    avr_t *avr;
    uint32_t freq;
    uint64_t held_cycles; /* simulated time spent held in reset (no instructions run) */
    int held;             /* the brown-out detector holds the MCU in reset */
    int pending_cause;    /* cause of a reset the harness itself triggers (-1: the watchdog's) */

    /* bridge */
    int master, slave, out_fd;
    double corrupt, drop;
    uint64_t rng;
    int uart_xoff;
    uint8_t rxq[65536];
    uint32_t rxq_head, rxq_tail;
    uint8_t txq[65536]; /* --uart-pipe: held until a "step" answer takes them (a pty takes them at once) */
    uint32_t txq_len;
    int uart_pipe; /* UART0 through the control pipe ("rx" in, "step" answers out), no pty traffic */
    uint64_t bytes_in, bytes_out, dropped_out, corrupted, dropped, lag_resets;
    uint64_t frames_in, frames_out; /* wire frames: a 0x00 ending at least one other byte (as sent) */
    int frame_open_in, frame_open_out;

    /* power */
    double battery_ocv_v, battery_ohm, ubec_set_v, ubec_dropout_v, bod_v, bod_release_v;
    double electronics_a, rotor_full_a;
    sag_t sags[MAX_SAGS];
    int n_sags;
    double battery_v, battery_a, ubec_v, ubec_a;
    uint32_t pin_mv[4];
    uint16_t pulse_us[16]; /* last complete pulse width on each pin (for the load model) */
    uint64_t rise[16];
    int level[16];
    int esc_supply_cut; /* the firmware's ESC supply cut pin is high: the rotor ESCs draw nothing */
    int power_external; /* the "power" command sets the four analog inputs: the caller's battery model */
    double ext_battery_v, ext_battery_a, ext_ubec_v, ext_ubec_a;

    /* watched RAM ("watch" command): recorded as M lines whenever it changes */
    uint16_t watch_addr, watch_len;
    uint8_t watched[16];
    int watch_valid;

    /* --stepped: simulated time moves only on "step" commands */
    int stepped, status; /* status: 3 once the firmware crashed the core (every later step fails) */

    /* self-test pin and scheduled hangs */
    double hangs[MAX_HANGS];
    int n_hangs;
    int selftest_low;

    const char *eeprom_path;

    /* usb.c (--usb): the pty carries the accessory's bulk data instead of UART0 */
    struct max3421e *max;
    uint64_t usb_to_board, usb_from_board, usb_dropped, usb_spi_bytes;

    /* record */
    FILE *record;
    uint64_t last_flush;
} harness_t;

static inline uint64_t harness_now(const harness_t *h) { return h->avr->cycle + h->held_cycles; }
static inline double harness_seconds(const harness_t *h) { return (double)harness_now(h) / h->freq; }

/* bridge.c */
int bridge_open(harness_t *h, const char *link);
void bridge_attach(harness_t *h);
void bridge_service(harness_t *h);
void bridge_close(harness_t *h, const char *link);
void bridge_receive(harness_t *h, uint8_t byte);
void bridge_transmit(harness_t *h, uint8_t byte);

/* power.c */
void power_init(harness_t *h);
void power_update(harness_t *h);
int power_add_sag(harness_t *h, double drop_v, double ramp_s, double duration_s, double at_s);

/* record.c */
void record_attach(harness_t *h);
void record_reset(harness_t *h, int cause);
void record_line(harness_t *h, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
void record_flush(harness_t *h);

/* ocr.c */
void ocr_attach(harness_t *h);
void ocr_reset(harness_t *h);

void record_watch(harness_t *h);

/* selftest / resets / running (main.c) */
int harness_run_until(harness_t *h, uint64_t target);
void harness_reset(harness_t *h, int cause);
void harness_set_selftest(harness_t *h, int low);
int harness_save_eeprom(harness_t *h);

/* usb.c */
int usb_attach(harness_t *h);
void usb_reset(harness_t *h);
void usb_service(harness_t *h);
void usb_command(harness_t *h, int argc, char **argv, FILE *out);
void usb_close(harness_t *h);

/* control.c: returns 0 to go on, 1 when asked to quit */
int control_service(harness_t *h, FILE *out);

#endif /* HARNESS_H */
