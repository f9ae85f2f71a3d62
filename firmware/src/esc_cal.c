/* esc_cal.c - ESC endpoint programming (see esc_cal.h). */
#include "esc_cal.h"

#include <avr/io.h>
#include <avr/pgmspace.h>

#include "app.h"
#include "board_pins.h"
#include "pulses.h"

#define E (board.esc)

static void set_supply_cut(uint8_t cut)
{
    E.supply_cut = cut;
    if (cut)
        PORTA |= _BV(ESC_SUPPLY_PIN_BIT);
    else
        PORTA &= (uint8_t)~_BV(ESC_SUPPLY_PIN_BIT);
}

void esc_cal_init(void)
{
    set_supply_cut(0);
    DDRA |= _BV(ESC_SUPPLY_PIN_BIT); /* ESC_SUPPLY_PIN_PORT 'A' */
    E.phase = ESC_CAL_PHASE_IDLE;
    E.abort = ESC_CAL_ABORT_NONE;
}

uint8_t esc_cal_active(void) { return E.phase >= ESC_CAL_PHASE_SUPPLY_OFF && E.phase <= ESC_CAL_PHASE_LOW; }

uint16_t esc_cal_width(uint8_t unit)
{
    if (!esc_cal_active() || unit != E.unit)
        return 0;
    return E.phase == ESC_CAL_PHASE_LOW ? E.low_us : E.high_us;
}

static void send_status(uint32_t now)
{
    esc_calibration_status_t m;
    m.unit = E.unit;
    m.phase = E.phase;
    m.abort = E.abort;
    uint16_t w = esc_cal_width(E.unit);
    m.pulse_us = w ? w : board.cfg.rotor_safe_us;
    m.supply_on = !E.supply_cut;
    m.phase_ms = now - E.phase_start_ms;
    report_send(MSG_ESC_CALIBRATION_STATUS, &m, 0, -1);
}

static void enter(uint8_t phase, uint32_t at, uint32_t duration_ms)
{
    E.phase = phase;
    E.phase_start_ms = at;
    E.deadline_ms = at + duration_ms;
    board.outputs_dirty = 1;
    if (phase == ESC_CAL_PHASE_SUPPLY_OFF || phase == ESC_CAL_PHASE_HIGH || phase == ESC_CAL_PHASE_LOW) {
        char name[12];
        report_name(PSTR(ESC_CAL_PHASE_NAMES), phase, name, sizeof name);
        report_log(SEVERITY_INFO, LOG_CODE_ESC_CALIBRATION, PSTR("ESC calibration of unit %u: %s"), E.unit,
                   name);
    }
    send_status(at);
}

static uint8_t start(const esc_calibrate_t *m, uint32_t now)
{
    if (board.state != BOARD_STATE_DISARMED)
        return NACK_REASON_BAD_STATE;
    if (esc_cal_active())
        return NACK_REASON_BUSY;
    uint8_t switched = board.cfg.esc_supply_switch;
    /* an endpoint past the frame's longest pulse would go out cut short (app.c, compute_outputs): the ESC
     * taught another endpoint than the one the host asked for and the board reported */
    if (m->unit >= board.cfg.n_units || m->high_us < m->low_us + ESC_MIN_SPAN_US ||
        (uint32_t)m->high_us * PULSE_FINE_PER_US > pulses_longest_fine() ||
        (switched && m->supply_off_ms < ESC_MIN_SUPPLY_OFF_MS))
        return NACK_REASON_OUT_OF_RANGE;
    if (board.power_state >= POWER_STATE_SHED)
        return NACK_REASON_POWER;
    E.unit = m->unit;
    E.low_us = m->low_us;
    E.high_us = m->high_us;
    E.high_ms = m->high_ms;
    E.low_ms = m->low_ms;
    E.abort = ESC_CAL_ABORT_NONE;
    if (switched) {
        report_log(SEVERITY_INFO, LOG_CODE_ESC_CALIBRATION,
                   PSTR("ESC calibration of unit %u: teaching %u-%u us (supply off for %u ms)"), E.unit,
                   E.low_us, E.high_us, m->supply_off_ms);
        set_supply_cut(1);
        enter(ESC_CAL_PHASE_SUPPLY_OFF, now, m->supply_off_ms);
    } else {
        report_log(SEVERITY_INFO, LOG_CODE_ESC_CALIBRATION,
                   PSTR("ESC calibration of unit %u: teaching %u-%u us (connect the ESC's supply when asked)"),
                   E.unit, E.low_us, E.high_us);
        enter(ESC_CAL_PHASE_WAIT_SUPPLY, now, ESC_SUPPLY_WAIT_MS);
        report_log(SEVERITY_WARNING, LOG_CODE_ESC_CALIBRATION,
                   PSTR("ESC calibration of unit %u: connect the ESC's supply now (%u us on channel %u); "
                        "waiting %u s"),
                   E.unit, E.high_us, 2u * E.unit + 1u, (unsigned)(ESC_SUPPLY_WAIT_MS / 1000u));
    }
    return 0;
}

uint8_t esc_cal_command(const esc_calibrate_t *m, uint32_t now)
{
    if (board.state == BOARD_STATE_BOOT)
        return NACK_REASON_BAD_STATE;
    if (m->confirm != ESC_CALIBRATION_CONFIRM)
        return NACK_REASON_UNCONFIRMED;
    if (m->step == ESC_CAL_STEP_SUPPLY_APPLIED) {
        if (E.phase != ESC_CAL_PHASE_WAIT_SUPPLY || m->unit != E.unit)
            return NACK_REASON_BAD_STATE;
        enter(ESC_CAL_PHASE_HIGH, now, E.high_ms);
        return 0;
    }
    return start(m, now);
}

void esc_cal_abort(uint8_t why, uint32_t now)
{
    if (!esc_cal_active())
        return;
    set_supply_cut(0);
    E.abort = why;
    enter(ESC_CAL_PHASE_ABORTED, now, 0);
    char name[16];
    report_name(PSTR(ESC_CAL_ABORT_NAMES), why, name, sizeof name);
    report_log(SEVERITY_WARNING, LOG_CODE_ESC_CALIBRATION,
               PSTR("ESC calibration of unit %u aborted (%s): channel at %u us"), E.unit, name,
               board.cfg.rotor_safe_us);
}

void esc_cal_poll(uint32_t now)
{
    while (esc_cal_active() && (int32_t)(now - E.deadline_ms) >= 0) {
        uint32_t due = E.deadline_ms;
        switch (E.phase) {
        case ESC_CAL_PHASE_SUPPLY_OFF:
            set_supply_cut(0);
            enter(ESC_CAL_PHASE_HIGH, due, E.high_ms);
            break;
        case ESC_CAL_PHASE_WAIT_SUPPLY:
            esc_cal_abort(ESC_CAL_ABORT_SUPPLY_TIMEOUT, due);
            break;
        case ESC_CAL_PHASE_HIGH:
            enter(ESC_CAL_PHASE_LOW, due, E.low_ms);
            break;
        default:
            enter(ESC_CAL_PHASE_DONE, due, 0);
            report_log(SEVERITY_INFO, LOG_CODE_ESC_CALIBRATION,
                       PSTR("ESC calibration of unit %u done: endpoints %u-%u us; channel back at %u us"),
                       E.unit, E.low_us, E.high_us, board.cfg.rotor_safe_us);
            break;
        }
    }
}

void esc_cal_report(uint32_t now)
{
    if (esc_cal_active())
        send_status(now);
}
