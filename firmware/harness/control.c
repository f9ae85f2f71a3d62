/*
 * control.c - commands on stdin (--control), one a line, each answered by one line on stdout:
 *
 *   now                       -> ok <cycles>          harness time
 *   noise <corrupt> <drop>    -> ok                   per-byte damage / loss probabilities, both ways
 *   hang                      -> ok <cycles>          pull the watchdog self-test pin low (main loop stops)
 *   sag <volts> <ramp> <dur>  -> ok <cycles>          battery sag starting now (seconds)
 *   battery <volts>           -> ok                   open-circuit battery voltage from now on
 *   reset                     -> ok <cycles>          press the reset button (EXTRF)
 *   clear                     -> ok                   no noise, no sags, self-test pin released
 *   flush                     -> ok <cycles>          the record file is complete up to <cycles>
 *   stats                     -> ok <bytes_in> <bytes_out> <dropped_out> <corrupted> <dropped> <lag_resets>
 *                                   <frames_in> <frames_out>
 *   eeprom                    -> ok                   write the EEPROM to its file now (--eeprom)
 *   mem <addr> <len>          -> ok <hex>             read data memory (RAM), at most 256 bytes
 *   quit                      -> ok                   stop (EEPROM saved, pty closed)
 * Lockstep (--stepped, --uart-pipe; firmware_sim.avr.stepped drives these):
 *   step <cycles>             -> ok <cycles> <tx>     run until harness time reaches <cycles> (the record
 *                                                     flushed); <tx>: the
 *                                                     bytes UART0 sent meanwhile in hex (--uart-pipe), or -
 *   rx <hex>                  -> ok                   bytes from the host into UART0's receive queue now
 *   power <bv> <ba> <uv> <ua> -> ok                   the analog inputs from now on (V, A, V, A): the
 *                                                     caller's battery and UBEC, brown-out included
 *   watch <addr> <len>        -> ok                   record RAM[addr..addr+len) as M lines when it changes
 * USB (--usb, usb.c):
 *   usb <fault> <value>       -> ok <cycles>          a fault of the phone or its cable (max3421e.h): nak N,
 *                                                     stall EP, detach, attach, aoa 0|1|2, packet 1..64,
 *                                                     zlp 0|1, never_switch 0|1|2, osc 0|1
 *   usbstate                  -> ok <mode> <s0>..<s5> <error> <to_board> <from_board> <dropped> <spi_bytes>
 *                                                     mode 0 detached, 1 normal, 2 accessory; the six strings
 *                                                     the board sent (SEND_STRING) and the model's last
 *                                                     protocol error in hex, "-" if empty; bytes the app
 *                                                     wrote to the board / read from it / dropped (no
 *                                                     accessory open); SPI bytes the MCU clocked
 * Anything else -> "error <why>", a line longer than 511 characters too (refused whole: an "rx" cut short
 * would lose bytes silently). Commands act between simulation slices (every simulated ms).
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "harness.h"

static char line[512];
static size_t line_len;
static int line_too_long; /* the line being read did not fit: it is refused whole, never cut short */

static int execute(harness_t *h, char *cmd, FILE *out)
{
    char *argv[8];
    int argc = 0;
    for (char *tok = strtok(cmd, " \t\r"); tok && argc < 8; tok = strtok(NULL, " \t\r"))
        argv[argc++] = tok;
    if (argc == 0)
        return 0;
    unsigned long long now = (unsigned long long)harness_now(h);
    const char *c = argv[0];
    if (!strcmp(c, "now") && argc == 1) {
        fprintf(out, "ok %llu\n", now);
    } else if (!strcmp(c, "noise") && argc == 3) {
        double corrupt = strtod(argv[1], NULL), drop = strtod(argv[2], NULL);
        if (!(corrupt >= 0 && corrupt <= 1 && drop >= 0 && drop <= 1)) {
            fprintf(out, "error noise: probabilities must lie in 0..1\n");
        } else {
            h->corrupt = corrupt;
            h->drop = drop;
            fprintf(out, "ok\n");
        }
    } else if (!strcmp(c, "hang") && argc == 1) {
        harness_set_selftest(h, 1);
        fprintf(out, "ok %llu\n", now);
    } else if (!strcmp(c, "sag") && argc == 4) {
        if (power_add_sag(h, strtod(argv[1], NULL), strtod(argv[2], NULL), strtod(argv[3], NULL),
                          harness_seconds(h)) < 0)
            fprintf(out, "error sag: need volts >= 0, ramp >= 0, duration > 0 (at most %d sags)\n", MAX_SAGS);
        else
            fprintf(out, "ok %llu\n", now);
    } else if (!strcmp(c, "battery") && argc == 2) {
        double v = strtod(argv[1], NULL);
        if (!(v >= 0 && v <= 60)) {
            fprintf(out, "error battery: volts must lie in 0..60\n");
        } else {
            h->battery_ocv_v = v;
            fprintf(out, "ok\n");
        }
    } else if (!strcmp(c, "reset") && argc == 1) {
        harness_reset(h, CAUSE_EXTERNAL);
        fprintf(out, "ok %llu\n", now);
    } else if (!strcmp(c, "clear") && argc == 1) {
        h->corrupt = h->drop = 0;
        h->n_sags = 0;
        h->n_hangs = 0;
        harness_set_selftest(h, 0);
        fprintf(out, "ok\n");
    } else if (!strcmp(c, "flush") && argc == 1) {
        record_flush(h);
        fprintf(out, "ok %llu\n", now);
    } else if (!strcmp(c, "stats") && argc == 1) {
        fprintf(out, "ok %llu %llu %llu %llu %llu %llu %llu %llu\n", (unsigned long long)h->bytes_in,
                (unsigned long long)h->bytes_out, (unsigned long long)h->dropped_out,
                (unsigned long long)h->corrupted, (unsigned long long)h->dropped,
                (unsigned long long)h->lag_resets, (unsigned long long)h->frames_in,
                (unsigned long long)h->frames_out);
    } else if (!strcmp(c, "eeprom") && argc == 1) {
        if (harness_save_eeprom(h) < 0)
            fprintf(out, "error eeprom: no --eeprom file, or it cannot be written\n");
        else
            fprintf(out, "ok\n");
    } else if (!strcmp(c, "mem") && argc == 3) {
        unsigned long addr = strtoul(argv[1], NULL, 0), len = strtoul(argv[2], NULL, 0);
        if (len > 256 || addr + len > (unsigned long)h->avr->ramend + 1u) {
            fprintf(out, "error mem: at most 256 bytes inside 0..0x%x\n", (unsigned)h->avr->ramend);
        } else {
            fprintf(out, "ok ");
            for (unsigned long i = 0; i < len; i++)
                fprintf(out, "%02x", h->avr->data[addr + i]);
            fprintf(out, "\n");
        }
    } else if (!strcmp(c, "step") && argc == 2) {
        unsigned long long target = strtoull(argv[1], NULL, 10);
        if (!h->stepped) {
            fprintf(out, "error step: only with --stepped\n");
        } else if (harness_run_until(h, target) != 0) {
            fprintf(out, "error step: the firmware crashed the simulated core at %.6f s\n", harness_seconds(h));
        } else {
            fprintf(out, "ok %llu ", (unsigned long long)harness_now(h));
            if (h->uart_pipe && h->txq_len) {
                for (uint32_t i = 0; i < h->txq_len; i++)
                    fprintf(out, "%02x", h->txq[i]);
                h->bytes_out += h->txq_len;
                h->txq_len = 0;
            } else {
                fputc('-', out);
            }
            fputc('\n', out);
            record_flush(h); /* the record is complete up to the answer's time */
        }
    } else if (!strcmp(c, "rx") && argc == 2) {
        size_t n = strlen(argv[1]);
        if (!h->uart_pipe || n % 2) {
            fprintf(out, "error rx: needs --uart-pipe and whole bytes in hex\n");
        } else {
            for (size_t i = 0; i < n; i += 2) {
                char pair[3] = {argv[1][i], argv[1][i + 1], 0};
                bridge_receive(h, (uint8_t)strtoul(pair, NULL, 16));
            }
            fprintf(out, "ok\n");
        }
    } else if (!strcmp(c, "power") && argc == 5) {
        double v[4];
        int good = 1;
        for (int i = 0; i < 4; i++) {
            v[i] = strtod(argv[i + 1], NULL);
            good &= v[i] >= 0 && v[i] <= 60;
        }
        if (!good) {
            fprintf(out, "error power: volts and amps must lie in 0..60\n");
        } else {
            h->power_external = 1;
            h->ext_battery_v = v[0], h->ext_battery_a = v[1], h->ext_ubec_v = v[2], h->ext_ubec_a = v[3];
            fprintf(out, "ok\n");
        }
    } else if (!strcmp(c, "watch") && argc == 3) {
        unsigned long addr = strtoul(argv[1], NULL, 0), len = strtoul(argv[2], NULL, 0);
        if (len == 0 || len > sizeof h->watched || addr + len > (unsigned long)h->avr->ramend + 1u) {
            fprintf(out, "error watch: 1..%u bytes inside 0..0x%x\n", (unsigned)sizeof h->watched,
                    (unsigned)h->avr->ramend);
        } else {
            h->watch_addr = (uint16_t)addr;
            h->watch_len = (uint16_t)len;
            h->watch_valid = 0;
            record_watch(h);
            fprintf(out, "ok\n");
        }
    } else if (!strcmp(c, "usb") || !strcmp(c, "usbstate")) {
        usb_command(h, argc, argv, out);
    } else if (!strcmp(c, "quit")) {
        fprintf(out, "ok\n");
        fflush(out);
        return 1;
    } else {
        fprintf(out, "error unknown command or wrong arguments: %s\n", c);
    }
    fflush(out);
    return 0;
}

int control_service(harness_t *h, FILE *out)
{
    for (;;) {
        char buf[256];
        ssize_t n = read(STDIN_FILENO, buf, sizeof buf);
        if (n == 0)
            return 1; /* stdin closed: the controlling process is gone */
        if (n < 0)
            return (errno == EAGAIN || errno == EINTR) ? 0 : 1;
        for (ssize_t i = 0; i < n; i++) {
            if (buf[i] != '\n') {
                if (line_len < sizeof line - 1)
                    line[line_len++] = buf[i];
                else
                    line_too_long = 1;
                continue;
            }
            line[line_len] = 0;
            line_len = 0;
            if (line_too_long) {
                line_too_long = 0;
                fprintf(out, "error line longer than %u characters: refused\n", (unsigned)sizeof line - 1);
                fflush(out);
                continue;
            }
            if (execute(h, line, out))
                return 1;
        }
    }
}
