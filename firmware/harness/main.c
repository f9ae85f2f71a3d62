/*
 * main.c - avr-harness: run an AVR firmware ELF on simavr behind a pseudo-terminal.
 *
 * The first line on stdout is the pty's path (like firmware-sim); with --control, stdout then carries
 * the answers to the commands read on stdin (control.c). Everything else, simavr's own chatter
 * included, goes to stderr. SIGINT/SIGTERM stop it cleanly (EEPROM saved, symlink removed, status 0);
 * a firmware that crashes the simulated core ends it with status 3.
 *
 * The process that starts it ties the harness's life to its own through stdin (--control or
 * --lifeline): a pipe whose write end only that process holds. The kernel closes that end however the
 * process dies, SIGKILL included, so end of file on stdin stops the harness as cleanly as SIGTERM: a
 * board nobody can reach any more must not keep serving its pty behind a stale symlink.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <getopt.h>
#include <math.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include <avr_eeprom.h>
#include <avr_extint.h>
#include <avr_ioport.h>
#include <sim_avr.h>
#include <sim_elf.h>
#include <sim_io.h>
#include <sim_irq.h>

#include "../include/board_pins.h"
#include "harness.h"

#define MCUSR_ADDR 0x54 /* MCUSR of the ATmega2560 in data space (I/O 0x34) */
#define MCUSR_PORF 0x01
#define MCUSR_EXTRF 0x02
#define MCUSR_BORF 0x04
#define SLICE_S 0.001
#define FLUSH_S 0.1

static const char USAGE[] =
    "usage: avr-harness [options] FIRMWARE.elf\n"
    "Run an ATmega2560 firmware on simavr with UART0 on a new pseudo-terminal (its path: first stdout "
    "line).\n"
    "\n"
    "  --freq HZ            CPU clock (default 16000000)\n"
    "  --unpaced            run as fast as the host allows (default: paced to wall time)\n"
    "  --duration S         stop after S seconds of simulated time\n"
    "  --link PATH          keep a symlink at PATH pointing at the pty\n"
    "  --record FILE        write pulse edges, resets, brown-outs to FILE (see record.c)\n"
    "  --eeprom FILE        EEPROM image loaded at start and saved back at exit\n"
    "  --battery V          battery open-circuit voltage (default 12.6: a full 3S LiPo)\n"
    "  --battery-ohm R      battery internal resistance (default 0.08)\n"
    "  --rotor-amps A       current of one rotor ESC at full throttle (default 4)\n"
    "  --sag V@T/RAMP[:DUR] battery loses V volts from T s, ramped over RAMP s, for DUR s (repeatable)\n"
    "  --hang-at T          pull the watchdog self-test pin low at T s (repeatable)\n"
    "  --corrupt P --drop P per-byte link damage / loss probabilities, both ways\n"
    "  --seed N             seed of the link noise\n"
    "  --control            read commands on stdin, answer on stdout (see control.c); stop at its end\n"
    "  --stepped            simulated time moves only on \"step\" commands (implies --control): lockstep\n"
    "  --uart-pipe          UART0 through the control pipe (\"rx\" in, \"step\" answers out), not the pty\n"
    "  --usb                the board's USB host port has an Android phone plugged in (usb.c); the pty\n"
    "                       (or --uart-pipe) is the phone's accessory app instead of UART0\n"
    "  --lifeline           stop (as on SIGTERM) when stdin reaches its end: the parent holds the\n"
    "                       other end of a pipe, so the harness ends however the parent dies\n"
    "\n"
    "examples:\n"
    "  avr-harness build/vscmg-adk.elf                       serve the board on a pty, real time\n"
    "  avr-harness --link /tmp/vscmg-board build/vscmg-adk.elf\n"
    "  avr-harness --sag 6@10/5 --hang-at 30 build/vscmg-adk.elf\n"
    "  avr-harness --unpaced --duration 5 --record edges.txt build/vscmg-adk.elf\n";

static volatile sig_atomic_t stop_requested;
static harness_t H;
static void (*core_reset)(avr_t *);
static avr_irq_t *selftest_irq;

static void on_signal(int sig)
{
    (void)sig;
    stop_requested = 1;
}

/* simavr's own sleep would usleep() while the MCU sleeps; pacing is done by the loop instead. */
static void no_sleep(avr_t *avr, avr_cycle_count_t cycles)
{
    (void)avr;
    (void)cycles;
}

static void quiet_logger(avr_t *avr, const int level, const char *format, va_list ap)
{
    (void)avr;
    if (level <= LOG_ERROR)
        vfprintf(stderr, format, ap);
}

/* Every reset of the core passes here (the watchdog's included): outputs off, the reset recorded. */
static void on_core_reset(avr_t *avr)
{
    if (core_reset)
        core_reset(avr);
    int cause = H.pending_cause == -2 ? CAUSE_WATCHDOG : H.pending_cause;
    ocr_reset(&H);
    usb_reset(&H);
    record_reset(&H, cause);
    if (selftest_irq) {
        /* A momentary self-test press ends with the reset, and the pin's pull-up reads high again. The
         * reset cleared PINK but not the irq's value: raised unchanged (1, after a reset no press caused:
         * a brown-out, the reset button) simavr filters it out, the pin read low from then on and no
         * later press could be seen (a hang after a brown-out never reset the MCU). Low, then high: the
         * pin is written whatever it was; nothing runs in between and the reset cleared PCMSK. */
        avr_raise_irq(selftest_irq, 0);
        avr_raise_irq(selftest_irq, 1);
    }
    H.selftest_low = 0;
}

void harness_reset(harness_t *h, int cause)
{
    h->pending_cause = cause;
    avr_reset(h->avr);
    h->pending_cause = -2;
    if (cause == CAUSE_BROWN_OUT)
        h->avr->data[MCUSR_ADDR] |= MCUSR_BORF;
    else if (cause == CAUSE_EXTERNAL)
        h->avr->data[MCUSR_ADDR] |= MCUSR_EXTRF;
}

void harness_set_selftest(harness_t *h, int low)
{
    if (low == h->selftest_low)
        return;
    h->selftest_low = low;
    record_line(h, "H %llu %d\n", (unsigned long long)harness_now(h), low);
    avr_raise_irq(selftest_irq, low ? 0 : 1);
}

/* The EEPROM's backing store inside simavr. (Its SET ioctl cannot write the last byte and reports
 * failure even when it succeeds; GET with no buffer hands out the store itself.) */
static uint8_t *eeprom_store(harness_t *h, uint32_t *size)
{
    avr_eeprom_desc_t d = {.ee = NULL, .offset = 0, .size = 0};
    avr_ioctl(h->avr, AVR_IOCTL_EEPROM_GET, &d);
    *size = h->avr->e2end + 1u;
    return d.ee;
}

static int eeprom_io(harness_t *h, const char *path, int save)
{
    uint32_t size;
    uint8_t *store = eeprom_store(h, &size);
    if (!store)
        return -1;
    if (save) {
        FILE *f = fopen(path, "wb");
        if (!f || fwrite(store, 1, size, f) != size) {
            fprintf(stderr, "avr-harness: cannot save EEPROM to %s: %s\n", path, strerror(errno));
            if (f)
                fclose(f);
            return -1;
        }
        return fclose(f);
    }
    FILE *f = fopen(path, "rb");
    if (!f)
        return errno == ENOENT ? 0 : -1; /* a fresh board: erased EEPROM */
    size_t n = fread(store, 1, size, f);
    fclose(f);
    return n == size || n == 0 ? 0 : -1;
}

int harness_save_eeprom(harness_t *h) { return h->eeprom_path ? eeprom_io(h, h->eeprom_path, 1) : -1; }

static int parse_sag(harness_t *h, const char *spec)
{
    double v, at = 0, ramp = 0, dur = INFINITY;
    char *end;
    v = strtod(spec, &end);
    if (*end == '@') {
        at = strtod(end + 1, &end);
        if (*end == '/')
            ramp = strtod(end + 1, &end);
        if (*end == ':')
            dur = strtod(end + 1, &end);
    }
    if (*end || power_add_sag(h, v, ramp, dur, at) < 0) {
        fprintf(stderr, "avr-harness: --sag %s: expected VOLTS[@AT[/RAMP][:DURATION]], e.g. 6@10/5\n", spec);
        return -1;
    }
    return 0;
}

static double number(const char *opt, const char *s, double lo, double hi)
{
    char *end;
    double v = strtod(s, &end);
    if (*end || !(v >= lo && v <= hi)) {
        fprintf(stderr, "avr-harness: %s %s: expected a number in %g..%g\n", opt, s, lo, hi);
        exit(2);
    }
    return v;
}

/* simavr polls a low INTn pin every cycle while INTn is in level-triggered mode (the reset default),
 * to re-raise the interrupt. The firmware enables no external interrupt, but INT4/INT5 share PE4/PE5
 * with pulse channels 4 and 5, which are low most of the time: that polling would make the simulation
 * several times slower than real time. Edge semantics for a disabled interrupt change nothing the
 * firmware can see. The core's reset turns the polling back on, so this runs after every slice. */
static void no_level_polling(harness_t *h)
{
    for (uint8_t i = 0; i < 8; i++)
        avr_extint_set_strict_lvl_trig(h->avr, i, 0);
}

static double wall_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* Paced mode: wait until wall time reaches `sim_s` (relative to *wall0), waking early for input. When the
 * host could not run us for a while (behind by more than MAX_LAG_S), simulated time does not race to
 * catch up: that would squeeze seconds of board time into milliseconds of wall time in which no host
 * byte can arrive, and trip the link watchdog for nothing. Instead the board's clock falls behind. */
#define MAX_LAG_S 0.02
static void pace(harness_t *h, double *wall0, double sim_s, int watch_stdin)
{
    double ahead = sim_s - (wall_seconds() - *wall0);
    if (ahead < -MAX_LAG_S) {
        *wall0 -= ahead; /* wall time of sim 0 moves later by the lag: from here on, in step again */
        h->lag_resets++;
        ahead = 0.0;
    }
    if (ahead <= 0)
        return;
    struct pollfd fds[2] = {{.fd = h->master, .events = POLLIN}, {.fd = STDIN_FILENO, .events = POLLIN}};
    struct timespec ts = {.tv_sec = (time_t)ahead, .tv_nsec = (long)((ahead - floor(ahead)) * 1e9)};
    ppoll(fds, watch_stdin ? 2 : 1, &ts, NULL);
}

/* --lifeline: whether stdin (non-blocking) has reached its end, the parent's end of the pipe closed.
 * Whatever is written on it is read and ignored; a read error counts as the end too. */
static int lifeline_cut(void)
{
    for (;;) {
        char buf[256];
        ssize_t n = read(STDIN_FILENO, buf, sizeof buf);
        if (n == 0)
            return 1;
        if (n < 0)
            return !(errno == EAGAIN || errno == EINTR);
    }
}

static uint64_t slice_cycles(const harness_t *h) { return (uint64_t)(h->freq * SLICE_S); }

/* One slice of `cycles` of harness time: bytes moved, the MCU run (or held in reset), the analog inputs,
 * the watched RAM and the scheduled hangs updated, the record flushed now and then. Returns 0, or 3 if the
 * firmware stopped the simulated core (the harness's exit status). */
static int run_slice(harness_t *h, uint64_t cycles)
{
    bridge_service(h);
    if (h->held) {
        h->held_cycles += cycles;
    } else {
        uint64_t target = h->avr->cycle + cycles;
        while (h->avr->cycle < target) {
            int state = avr_run(h->avr);
            if (state == cpu_Done || state == cpu_Crashed) {
                fprintf(stderr, "avr-harness: the firmware %s at %.6f s (pc 0x%x)\n",
                        state == cpu_Done ? "stopped (sleep with interrupts off)" : "crashed",
                        harness_seconds(h), (unsigned)h->avr->pc);
                return 3;
            }
        }
    }
    no_level_polling(h);
    bridge_service(h);
    power_update(h);
    record_watch(h);
    double t = harness_seconds(h);
    for (int i = 0; i < h->n_hangs; i++) {
        if (h->hangs[i] <= t) {
            harness_set_selftest(h, 1);
            h->hangs[i--] = h->hangs[--h->n_hangs];
        }
    }
    if (harness_now(h) - h->last_flush >= (uint64_t)(h->freq * FLUSH_S))
        record_flush(h);
    return 0;
}

/* --stepped: run until harness time reaches `target` cycles, in slices of at most SLICE_S (the link and
 * the analog inputs are serviced between slices, as in the paced loop). 0, or 3 if the firmware crashed
 * (then every later step fails too). */
int harness_run_until(harness_t *h, uint64_t target)
{
    while (!h->status && harness_now(h) < target) {
        uint64_t left = target - harness_now(h), slice = slice_cycles(h);
        h->status = run_slice(h, left < slice ? left : slice);
    }
    return h->status;
}

int main(int argc, char **argv)
{
    static const struct option opts[] = {
        {"freq", required_argument, 0, 'f'},
        {"unpaced", no_argument, 0, 'u'},
        {"duration", required_argument, 0, 'd'},
        {"link", required_argument, 0, 'l'},
        {"record", required_argument, 0, 'r'},
        {"eeprom", required_argument, 0, 'e'},
        {"battery", required_argument, 0, 'b'},
        {"battery-ohm", required_argument, 0, 'o'},
        {"rotor-amps", required_argument, 0, 'a'},
        {"sag", required_argument, 0, 's'},
        {"hang-at", required_argument, 0, 'H'},
        {"corrupt", required_argument, 0, 'c'},
        {"drop", required_argument, 0, 'p'},
        {"seed", required_argument, 0, 'S'},
        {"control", no_argument, 0, 'C'},
        {"lifeline", no_argument, 0, 'L'},
        {"stepped", no_argument, 0, 'T'},
        {"uart-pipe", no_argument, 0, 'U'},
        {"usb", no_argument, 0, 'B'},
        {"help", no_argument, 0, 'h'},
        {0, 0, 0, 0},
    };
    harness_t *h = &H;
    memset(h, 0, sizeof *h);
    h->freq = 16000000;
    h->pending_cause = -2;
    h->battery_ocv_v = 12.6;
    h->battery_ohm = 0.08;
    h->rotor_full_a = 4.0;
    h->ubec_set_v = 5.0;
    h->ubec_dropout_v = 0.5;
    h->bod_v = 4.3;
    h->bod_release_v = 4.5;
    h->electronics_a = 0.15;
    h->rng = 0x9E3779B97F4A7C15ULL;
    int paced = 1, control = 0, lifeline = 0, usb = 0;
    double duration = INFINITY;
    const char *link = NULL, *record = NULL, *eeprom = NULL;

    /* A stop asked for at any time, even before the pty exists, is a clean stop: once the pty path is
     * out, whoever read it may signal us at once, and must find the handler in place. */
    struct sigaction sa = {.sa_handler = on_signal};
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);

    /* Our stdout is the pty path and command answers only: keep a private copy of it and send the
     * library's prints (fd 1) to stderr. */
    h->out_fd = dup(STDOUT_FILENO);
    dup2(STDERR_FILENO, STDOUT_FILENO);
    FILE *out = fdopen(h->out_fd, "w");

    for (int c; (c = getopt_long(argc, argv, "h", opts, NULL)) != -1;) {
        switch (c) {
        case 'f':
            h->freq = (uint32_t)number("--freq", optarg, 1e5, 1e8);
            break;
        case 'u':
            paced = 0;
            break;
        case 'd':
            duration = number("--duration", optarg, 0, 1e9);
            break;
        case 'l':
            link = optarg;
            break;
        case 'r':
            record = optarg;
            break;
        case 'e':
            eeprom = optarg;
            break;
        case 'b':
            h->battery_ocv_v = number("--battery", optarg, 0, 60);
            break;
        case 'o':
            h->battery_ohm = number("--battery-ohm", optarg, 0, 10);
            break;
        case 'a':
            h->rotor_full_a = number("--rotor-amps", optarg, 0, 100);
            break;
        case 's':
            if (parse_sag(h, optarg) < 0)
                return 2;
            break;
        case 'H':
            if (h->n_hangs == MAX_HANGS) {
                fprintf(stderr, "avr-harness: too many --hang-at\n");
                return 2;
            }
            h->hangs[h->n_hangs++] = number("--hang-at", optarg, 0, 1e9);
            break;
        case 'c':
            h->corrupt = number("--corrupt", optarg, 0, 1);
            break;
        case 'p':
            h->drop = number("--drop", optarg, 0, 1);
            break;
        case 'S':
            h->rng ^= (uint64_t)number("--seed", optarg, 0, 1e18) * 0x2545F4914F6CDD1DULL;
            break;
        case 'C':
            control = 1;
            break;
        case 'L':
            lifeline = 1;
            break;
        case 'T':
            h->stepped = control = 1;
            break;
        case 'U':
            h->uart_pipe = 1;
            break;
        case 'B':
            usb = 1;
            break;
        case 'h':
            fputs(USAGE, stderr);
            return 0;
        default:
            fputs(USAGE, stderr);
            return 2;
        }
    }
    if (optind != argc - 1) {
        fputs(USAGE, stderr);
        return 2;
    }
    if (!h->rng)
        h->rng = 1;

    avr_global_logger_set(quiet_logger);
    elf_firmware_t fw;
    memset(&fw, 0, sizeof fw);
    if (access(argv[optind], R_OK) < 0 || elf_read_firmware(argv[optind], &fw) < 0) {
        fprintf(stderr, "avr-harness: cannot load %s: %s\n", argv[optind], strerror(errno));
        return 2;
    }
    h->avr = avr_make_mcu_by_name("atmega2560");
    if (!h->avr || avr_init(h->avr) < 0) {
        fprintf(stderr, "avr-harness: simavr has no ATmega2560 core\n");
        return 2;
    }
    avr_load_firmware(h->avr, &fw);
    h->avr->frequency = h->freq;
    h->avr->sleep = no_sleep; /* the harness paces time itself */
    core_reset = h->avr->reset;
    h->avr->reset = on_core_reset;

    if (record) {
        h->record = fopen(record, "w");
        if (!h->record) {
            fprintf(stderr, "avr-harness: cannot write %s: %s\n", record, strerror(errno));
            return 2;
        }
    }
    h->eeprom_path = eeprom;
    if (eeprom && eeprom_io(h, eeprom, 0) < 0) {
        fprintf(stderr, "avr-harness: cannot load EEPROM from %s\n", eeprom);
        return 2;
    }
    record_attach(h);
    ocr_attach(h);
    selftest_irq = avr_io_getirq(h->avr, AVR_IOCTL_IOPORT_GETIRQ(SELFTEST_PIN_PORT), SELFTEST_PIN_BIT);
    avr_raise_irq(selftest_irq, 1); /* the pin's pull-up: released */
    bridge_attach(h);
    if (usb && usb_attach(h) < 0) {
        fprintf(stderr, "avr-harness: --usb: cannot wire the MAX3421E model (no SPI or ports on this core?)\n");
        return 2;
    }
    power_init(h);
    no_level_polling(h);
    h->avr->data[MCUSR_ADDR] = MCUSR_PORF;
    record_line(h, "R 0 %d\n", CAUSE_POWER_ON);
    if (bridge_open(h, link) < 0)
        return 2;
    if (control || lifeline)
        fcntl(STDIN_FILENO, F_SETFL, fcntl(STDIN_FILENO, F_GETFL) | O_NONBLOCK);

    double wall0 = wall_seconds();
    int status = 0;
    while (!stop_requested) {
        if (h->stepped) { /* time moves only in "step" commands: wait for the next one */
            struct pollfd in = {.fd = STDIN_FILENO, .events = POLLIN};
            struct timespec wait = {.tv_sec = 0, .tv_nsec = 100000000L};
            ppoll(&in, 1, &wait, NULL);
            if (control_service(h, out) || h->status)
                break;
            continue;
        }
        if (harness_seconds(h) >= duration)
            break;
        if ((status = run_slice(h, slice_cycles(h))) != 0)
            goto done;
        if (control && control_service(h, out))
            break;
        if (!control && lifeline && lifeline_cut()) {
            fprintf(stderr, "avr-harness: stdin closed (the process that started it is gone): stopping\n");
            break;
        }
        if (paced)
            pace(h, &wall0, harness_seconds(h), control || lifeline);
    }
    status = status ? status : h->status;
done:
    record_flush(h);
    if (h->record)
        fclose(h->record);
    if (eeprom && eeprom_io(h, eeprom, 1) < 0)
        status = status ? status : 1;
    bridge_close(h, link);
    if (h->max)
        usb_close(h);
    fprintf(stderr,
            "avr-harness: stopped at %.3f s; %llu bytes in, %llu out, %llu dropped; %llu lag resets\n",
            harness_seconds(h), (unsigned long long)h->bytes_in, (unsigned long long)h->bytes_out,
            (unsigned long long)h->dropped_out, (unsigned long long)h->lag_resets);
    return status;
}
