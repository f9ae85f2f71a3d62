/*
 * esc_cal.h - ESC endpoint programming: the usual hobby-ESC procedure on one rotor channel, timed by the
 * board (firmware_sim/board/esc_calibration.py rule for rule; docs/protocol.md, "ESC endpoint
 * programming").
 *
 *   EscCalibrate(START), DISARMED, confirmed:
 *     supply switch wired: SUPPLY_OFF (ESC supply cut, channel at high_us, supply_off_ms) -> HIGH
 *     no switch:           WAIT_SUPPLY (channel at high_us; EscCalibrate(SUPPLY_APPLIED) -> HIGH; 60 s)
 *   HIGH (high_us, high_ms: the ESC's acknowledgement) -> LOW (low_us, low_ms) -> DONE (safe pulse)
 *
 * Disarm, Hello, link loss, load shedding and the supply wait running out abort it (the channel to the
 * safe pulse at once, the switch released); a reset stops it with everything else. Times in ms of uptime.
 */
#ifndef ESC_CAL_H
#define ESC_CAL_H

#include <stdint.h>

#include "protocol_gen.h"

typedef struct {
    uint8_t phase, abort, unit, supply_cut; /* ESC_CAL_PHASE_*, ESC_CAL_ABORT_* */
    uint16_t low_us, high_us, high_ms, low_ms;
    uint32_t phase_start_ms, deadline_ms;
} esc_cal_t;

/* At boot: the supply switch output low (the ESCs powered), no procedure. */
void esc_cal_init(void);
/* EscCalibrate at `now`: 0 (accepted) or the NACK reason. */
uint8_t esc_cal_command(const esc_calibrate_t *m, uint32_t now);
/* Stop now if running (ESC_CAL_ABORT_*): the channel to the safe pulse, the supply switch released. */
void esc_cal_abort(uint8_t why, uint32_t now);
/* The phases whose deadlines have passed at `now`. */
void esc_cal_poll(uint32_t now);
/* The periodic status while running (at the telemetry rate). */
void esc_cal_report(uint32_t now);
uint8_t esc_cal_active(void);
/* The width (us) the procedure puts on rotor channel of `unit`, or 0 if it does not drive it. */
uint16_t esc_cal_width(uint8_t unit);

#endif /* ESC_CAL_H */
