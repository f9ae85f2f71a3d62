/*
 * app.h - the board: the C twin of firmware_sim/board.py (state machine, link watchdog, commands,
 * calibration transfers, power stages, outputs) on real hardware.
 *
 * app.c handles what arrives and decides the outputs; report.c builds and sends what leaves (HelloReply,
 * Telemetry, Heartbeat, Log, Ack/Nack, calibration fragments). main.c owns start-up and the loop.
 * Times are milliseconds of uptime (clock_ms()).
 */
#ifndef APP_H
#define APP_H

#include <stdint.h>

#include "adc.h"
#include "config.h"
#include "esc_cal.h"
#include "frame.h"
#include "link.h"
#include "power.h"
#include "uart.h"

#define MAX_HW_CHANNELS (2u * MAX_HW_UNITS)
#define CAL_DOWNLOAD_RETRY_MS 100u
#define CAL_DOWNLOAD_TRIES 5u

/* A schedule of deadlines origin + k * period (like firmware_sim/board/periodic.py), in ms of uptime. */
typedef struct {
    uint64_t at;     /* the next deadline in 1/256 us */
    uint32_t period; /* in 1/256 us */
    uint32_t next;   /* the next deadline in ms */
    uint8_t enabled;
} periodic_t;

typedef struct {
    uint8_t active, unit, transfer_id, count;
    uint16_t set_crc; /* the set's CRC, in every fragment: computed once (the set cannot change meanwhile) */
    uint8_t seq[REASM_MAX_FRAGMENTS], tries[REASM_MAX_FRAGMENTS], acked[REASM_MAX_FRAGMENTS];
    uint32_t retry_ms[REASM_MAX_FRAGMENTS];
} download_t;

typedef struct {
    board_config_t cfg;
    uint8_t n_channels;
    uint8_t reset_cause; /* RESET_CAUSE_* */
    uint32_t boot_id;    /* this boot's id (storage_new_boot_id), in HelloReply and Heartbeat */
    uint8_t state, mode, power_state, gimbal_mode;
    uint8_t session, link_lost, have_rx, shed_latched, clamped, ubec_over, outputs_dirty;
    uint32_t last_rx_ms;
    float gimbal_cmd[MAX_HW_UNITS], rotor_cmd[MAX_HW_UNITS];
    uint16_t raw_cmd[MAX_HW_CHANNELS];
    uint8_t have_raw;
    uint16_t outputs[MAX_HW_CHANNELS]; /* widths on the pins (us; 0: no pulse) */
    unit_state_t units[MAX_HW_UNITS];  /* open-loop estimates from the outputs (no sensors on the units) */
    power_reading_t power;
    power_manager_t pm;
    power_params_t power_params;
    float conversion_v; /* filtered battery voltage used by the rotor maps, 10 mV steps */
    periodic_t telemetry, heartbeat;
    uint32_t next_power_ms;
    uint8_t tx_seq;
    uint32_t setpoints, bad_setpoints, ignored_setpoints, ignored, tx_dropped;
    uart_stats_t rx_lost; /* receive losses already reported in a Log */
    deframer_t deframer;
    frame_t frame;
    answer_cache_t answers;
    reassembler_t reasm;
    download_t download;
    esc_cal_t esc; /* the ESC endpoint procedure (esc_cal.c) */
} board_t;

extern board_t board;

/* app.c */
void app_boot(uint8_t reset_cause, config_status_t config, uint8_t config_problem);
/* One pass of the main loop's work at `now` (ms); 1 if work is left for the next pass (do not sleep). */
uint8_t app_poll(uint32_t now);
/* From the 1 kHz tick interrupt: the link watchdog's stop (see app.c). */
void app_tick(uint32_t now_ms);

/* report.c */
void report_send(uint8_t msg_id, const void *msg, uint8_t flags, int16_t seq);
void report_log(uint8_t severity, uint16_t code, const char *fmt_flash, ...);
void report_heartbeat(uint32_t now);
void report_telemetry(uint32_t now);
void report_hello_reply(void);
void report_answer(const frame_t *f, uint8_t answer);
void report_cal_fragment(uint8_t index, uint8_t retry);
/* Names of enum values for logs, into `out` (room for n bytes). */
void report_name(const char *names_flash, uint8_t value, char *out, unsigned n);

/* periodic schedules (app.c) */
void periodic_start(periodic_t *p, float rate_hz, uint32_t origin, uint8_t first_offset);
uint8_t periodic_due(periodic_t *p, uint32_t now);

#endif /* APP_H */
