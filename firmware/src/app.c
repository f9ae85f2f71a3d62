/*
 * app.c - what the board does with what arrives, and the outputs it decides (see app.h).
 *
 * Follows firmware_sim/board.py rule for rule (docs/protocol.md: board states, link watchdog, reliable
 * commands, calibration transfers); differences are only where real hardware differs: no sensors on
 * the units (their telemetry states are estimates from the outputs, and a dead ESC cannot be
 * detected), and power is measured on the ADC instead of modelled.
 */
#include "app.h"

#include <avr/pgmspace.h>
#include <math.h>
#include <string.h>
#include <util/atomic.h>

#include "calib.h"
#include "clock.h"
#include "crc16.h"
#include "esc_cal.h"
#include "port.h"
#include "pulses.h"
#include "state.h"
#include "storage.h"
#include "uart.h"

board_t board;

#define VOLT_QUANTUM 0.01f /* rotor conversions use the battery voltage in 10 mV steps */

/* ------------------------------------------------------------------------------------------ schedules */
#define PERIODIC_UNITS_PER_MS 256000ULL /* deadlines are kept in 1/256 us: no drift over days */

void periodic_start(periodic_t *p, float rate_hz, uint32_t origin, uint8_t first_offset)
{
    p->period = (uint32_t)lrintf(1e6f * 256.0f / rate_hz);
    p->at = (uint64_t)origin * PERIODIC_UNITS_PER_MS + (first_offset ? p->period : 0u);
    p->next = (uint32_t)(p->at / PERIODIC_UNITS_PER_MS);
    p->enabled = 1;
}

/* Due at `now`? Then move past it (deadlines missed in one jump are skipped, not replayed). */
uint8_t periodic_due(periodic_t *p, uint32_t now)
{
    if (!p->enabled || (int32_t)(now - p->next) < 0)
        return 0;
    while ((int32_t)(now - p->next) >= 0) {
        p->at += p->period;
        p->next = (uint32_t)(p->at / PERIODIC_UNITS_PER_MS);
    }
    return 1;
}

/* ------------------------------------------------------------------------------------------ outputs */
/*
 * Widths are fine widths (1/512 us, pulses.h): a map's float us rounded to 1/512 us, which the pulse stage
 * dithers over frames in whole 0.5 us ticks; whole-us widths (the safe pulse, raw pulses, ESC endpoints)
 * are whole ticks (<< 9). board.outputs keeps the whole us each is reported as.
 *
 * A calibration map costs 0.3-0.9 ms of float arithmetic on the ATmega, so conversions are cached
 * (recomputed only when their inputs change) and computed one per main-loop pass (convert_step), which
 * keeps every pass short: the watchdog check-in, the link watchdog and received bytes never wait behind
 * a burst of conversions. Outputs that need no map (safe rotor pulse, raw pulses, gimbal hold in RATE
 * mode) take effect at once.
 */
typedef struct {
    float input, arg; /* the command and its second input (battery volts or gimbal mode) */
    uint32_t fine;
    uint8_t clamp, valid;
} conv_cache_t;

typedef struct {
    uint32_t fine; /* the width (1/512 us) the value stands for */
    float arg;   /* battery volts or gimbal mode the value was computed for */
    float value; /* rotor: steady speed rad/s; gimbal: rate rad/s or angle rad the pulse stands for */
    uint8_t valid;
} value_cache_t;

static conv_cache_t gimbal_conv[MAX_HW_UNITS], rotor_conv[MAX_HW_UNITS];
static value_cache_t rotor_target[MAX_HW_UNITS], gimbal_target[MAX_HW_UNITS];
static float rotor_decay_up, rotor_decay_down, gimbal_decay; /* per frame, from the time constants */

/* A map's width (us) as a fine width: 1/512 us, round half to even as protocol/pulse_widths.py. */
static uint32_t to_fine(float value)
{
    long w = lrintf(value * (float)PULSE_FINE_PER_US);
    return (uint32_t)(w < 0 ? 0 : (w > (long)PULSE_MAX_US * PULSE_FINE_PER_US ? (long)PULSE_MAX_US * PULSE_FINE_PER_US : w));
}

static uint32_t whole_us(uint16_t us) { return (uint32_t)us * PULSE_FINE_PER_US; }

static float fine_us(uint32_t fine) { return (float)fine * (1.0f / (float)PULSE_FINE_PER_US); }

static uint8_t calibrations_complete(void)
{
    for (uint8_t u = 0; u < board.cfg.n_units; u++)
        if (!storage_cal(u, 0))
            return 0;
    return 1;
}

static void forget_conversions(uint8_t unit)
{
    gimbal_conv[unit].valid = rotor_conv[unit].valid = 0;
    rotor_target[unit].valid = gimbal_target[unit].valid = 0;
}

/* Rotors stopped (motors off, or a new Arm): no command, and no width cached for an earlier one. Rotor
 * conversions are not refreshed while the motors are off (armed_converting), so a width cached before a
 * Disarm would otherwise drive the rotors at the old speed after the next Arm, until the zero command had
 * been converted (a reviewer saw 2000 us for up to five frames). A rotor width is used only if it was
 * converted since the last Arm. */
static void stop_rotors(void)
{
    memset(board.rotor_cmd, 0, sizeof board.rotor_cmd);
    board.have_raw = 0;
    for (uint8_t u = 0; u < MAX_HW_UNITS; u++)
        rotor_conv[u].valid = 0;
}

static uint8_t armed_converting(void)
{
    return motors_enabled(board.state) && !board.shed_latched && board.power_state < POWER_STATE_SHED &&
           !(board.mode == CONTROL_MODE_RAW_PULSES && board.have_raw);
}

/*
 * The conversions come in slots: 2u a unit's gimbal command, 2u+1 its rotor command (the widths to put
 * out), and the value of each channel's present width (the estimates' targets). Each has a round-robin
 * cursor, so a stale slot waits for at most one turn of the others: scanning from unit 0 every pass let a
 * host streaming fast-changing gimbal commands at 200 Hz starve every later unit's conversions for as
 * long as the stream lasted (their rotors never followed, the board ARMED and counting the setpoints).
 * Commands come first, but each turn of the command cursor owes the values one conversion, so under a
 * stream the board cannot keep up with, the estimates lag but are never abandoned.
 */
static uint8_t command_next, value_next, value_owed;

/* Slot `s`'s command conversion, if stale: 1 if one was computed. */
static uint8_t convert_command(uint8_t s, const uint8_t *cal, uint8_t raw)
{
    uint8_t u = (uint8_t)(s >> 1);
    if (s & 1u) {
        conv_cache_t *r = &rotor_conv[u];
        if (!armed_converting() ||
            (r->valid && r->input == board.rotor_cmd[u] && r->arg == board.conversion_v))
            return 0;
        cal_conv_t c = cal_rotor_pulse_us(cal, board.rotor_cmd[u], board.conversion_v);
        *r = (conv_cache_t){board.rotor_cmd[u], board.conversion_v, to_fine(c.value), c.clamp, 1};
        return 1;
    }
    conv_cache_t *g = &gimbal_conv[u];
    float mode = (float)board.gimbal_mode;
    if (raw || (g->valid && g->input == board.gimbal_cmd[u] && g->arg == mode))
        return 0;
    cal_conv_t c = cal_gimbal_pulse_us(cal, board.gimbal_cmd[u], board.gimbal_mode);
    *g = (conv_cache_t){board.gimbal_cmd[u], mode, to_fine(c.value), c.clamp, 1};
    return 1;
}

/* Slot `s`'s value conversion (what channel s's present width stands for), if stale: 1 if computed. */
static uint8_t convert_value(uint8_t s, const uint8_t *cal)
{
    uint8_t u = (uint8_t)(s >> 1);
    uint32_t fine = pulses_get(s);
    if (!fine)
        return 0;
    if (s & 1u) {
        value_cache_t *r = &rotor_target[u];
        if (r->valid && r->fine == fine && r->arg == board.conversion_v)
            return 0;
        *r = (value_cache_t){fine, board.conversion_v,
                             cal_rotor_speed(cal, fine_us(fine), board.conversion_v).value, 1};
        return 1;
    }
    value_cache_t *g = &gimbal_target[u];
    float mode = (float)board.gimbal_mode;
    if (g->valid && g->fine == fine && g->arg == mode)
        return 0;
    *g = (value_cache_t){fine, mode, cal_gimbal_value(cal, fine_us(fine), board.gimbal_mode).value, 1};
    return 1;
}

/* The next stale value conversion from the value cursor on: 1 if one was computed. */
static uint8_t value_step(uint8_t slots)
{
    for (uint8_t k = 0; k < slots; k++) {
        uint8_t s = value_next;
        value_next = (uint8_t)(s + 1u < slots ? s + 1u : 0u);
        const uint8_t *cal = storage_cal((uint8_t)(s >> 1), 0);
        if (cal && convert_value(s, cal))
            return 1;
    }
    return 0;
}

/* Bring one stale conversion up to date: 1 if one was computed (more may be stale), else 0. */
static uint8_t convert_step(void)
{
    uint8_t slots = board.n_channels;
    if (command_next >= slots || value_next >= slots)
        command_next = value_next = 0;
    if (value_owed) {
        value_owed = 0;
        if (value_step(slots))
            return 1;
    }
    uint8_t raw = motors_enabled(board.state) && board.mode == CONTROL_MODE_RAW_PULSES && board.have_raw;
    for (uint8_t k = 0; k < slots; k++) {
        uint8_t s = command_next;
        command_next = (uint8_t)(s + 1u < slots ? s + 1u : 0u);
        if (!command_next)
            value_owed = 1; /* a turn of the commands: the values' turn next */
        const uint8_t *cal = storage_cal((uint8_t)(s >> 1), 0);
        if (cal && convert_command(s, cal, raw))
            return 1;
    }
    value_owed = 0;
    return value_step(slots);
}

/* The fine pulse widths for protocol state `state`, the command and the power stage (board.py:
 * _compute_outputs), from the cached conversions. */
static void compute_outputs(uint32_t *out, uint8_t state)
{
    const board_config_t *c = &board.cfg;
    uint8_t clamped = 0;
    uint8_t armed = motors_enabled(state);
    uint8_t shed = board.shed_latched || board.power_state >= POWER_STATE_SHED;
    uint8_t raw = armed && board.mode == CONTROL_MODE_RAW_PULSES && board.have_raw;
    for (uint8_t u = 0; u < c->n_units; u++) {
        const uint8_t *cal = storage_cal(u, 0);
        const conv_cache_t *gc = &gimbal_conv[u], *rc = &rotor_conv[u];
        uint32_t g, r;
        if (raw) {
            g = whole_us(board.raw_cmd[2 * u]);
        } else if (!cal) {
            g = 0;
        } else if (board.gimbal_mode == GIMBAL_MODE_RATE && board.gimbal_cmd[u] == 0.0f) {
            g = to_fine(
                cal_gimbal_pulse_us(cal, 0.0f, GIMBAL_MODE_RATE).value); /* the hold pulse: no solving */
        } else {
            clamped |= gc->valid && gc->clamp != CAL_CLAMP_NONE && armed;
            g = gc->valid ? gc->fine : pulses_get((uint8_t)(2 * u));
        }
        if (!armed || shed) {
            r = whole_us(c->rotor_safe_us);
        } else if (raw) {
            r = whole_us(board.raw_cmd[2 * u + 1]);
        } else if (!cal) {
            r = whole_us(c->rotor_safe_us);
        } else {
            clamped |= rc->valid && rc->clamp != CAL_CLAMP_NONE;
            r = rc->valid ? rc->fine : whole_us(c->rotor_safe_us);
        }
        uint16_t esc = esc_cal_width(u); /* the ESC endpoint procedure drives this rotor channel */
        if (esc)
            r = whole_us(esc);
        if (armed && !shed && board.power_state == POWER_STATE_LIMIT && cal) {
            float lo = cal_esc_low_us(cal), hi = cal_esc_high_us(cal);
            uint32_t cap = to_fine(lo + c->limit_throttle * (hi - lo));
            if (r > cap) {
                r = cap;
                clamped = 1;
            }
        }
        /* no width past the frame's end: at 490 Hz a 2500 us raw pulse or map width held the pin high for
         * good (firmware_sim/board/config.py: longest_pulse_fine) */
        uint32_t longest = pulses_longest_fine();
        if (g > longest || r > longest) {
            g = g > longest ? longest : g;
            r = r > longest ? longest : r;
            clamped = 1;
        }
        out[2 * u] = g;
        out[2 * u + 1] = r;
    }
    board.clamped = clamped;
}

static void apply_outputs_for(uint8_t state)
{
    uint32_t out[MAX_HW_CHANNELS];
    compute_outputs(out, state);
    for (uint8_t ch = 0; ch < board.n_channels; ch++) {
        /* reported even when the timer already has it: the tick interrupt sets a failsafe's safe widths
         * on the pins before the main loop gets here, and telemetry must say what the pins say */
        board.outputs[ch] = pulses_reported_us(out[ch]);
        if (out[ch] != pulses_get(ch))
            pulses_set(ch, out[ch]);
    }
    board.outputs_dirty = 0;
}

static void apply_outputs(void) { apply_outputs_for(board.state); }

static float clampf(float x, float limit) { return x > limit ? limit : (x < -limit ? -limit : x); }

/* Advance the units' estimated states by one pulse frame of dt seconds: actuators.py's first-order
 * responses towards what the outputs command (the board has no sensors on the units). */
static void estimate_units(float dt)
{
    for (uint8_t u = 0; u < board.cfg.n_units; u++) {
        unit_state_t *s = &board.units[u];
        const value_cache_t *rt = &rotor_target[u], *gt = &gimbal_target[u];
        /* an ESC being programmed does not run its motor */
        float target = board.outputs[2 * u + 1] && rt->valid && !esc_cal_width(u) ? rt->value : 0.0f;
        float decay = target > s->rotor_speed ? rotor_decay_up : rotor_decay_down;
        s->rotor_speed = clampf(target + (s->rotor_speed - target) * decay, ROTOR_SPEED_LIMIT);
        float rate = 0.0f;
        if (board.outputs[2 * u] && gt->valid) {
            if (board.gimbal_mode == GIMBAL_MODE_RATE) {
                float want = clampf(gt->value, CFG_DEFAULT_GIMBAL_MAX_RATE_RAD_S);
                rate = want + (s->gimbal_rate - want) * gimbal_decay;
            } else {
                float err = gt->value - s->gimbal_angle;
                rate = clampf(err / CFG_DEFAULT_GIMBAL_TIME_CONSTANT_S, CFG_DEFAULT_GIMBAL_MAX_RATE_RAD_S);
                if (fabsf(rate * dt) > fabsf(err))
                    rate = err / dt;
            }
        }
        s->gimbal_rate = clampf(rate, GIMBAL_RATE_LIMIT);
        s->gimbal_angle = clampf(s->gimbal_angle + rate * dt, GIMBAL_ANGLE_LIMIT);
    }
}

/* ------------------------------------------------------------------------------------------ state */
static uint8_t power_ok(void) { return board.power_state < POWER_STATE_SHED; }

/* Gimbals hold: zero rate in RATE mode, the present (estimated) angle in ANGLE mode. */
static void hold_gimbals(void)
{
    for (uint8_t u = 0; u < board.cfg.n_units; u++)
        board.gimbal_cmd[u] = board.gimbal_mode == GIMBAL_MODE_RATE ? 0.0f : board.units[u].gimbal_angle;
}

/* The new state's outputs take effect before anything is reported: formatting a Log and a Heartbeat
 * takes ~1 ms of CPU each, and a stop (FAILSAFE, DISARMED, BOOT) must reach the timers first so that it
 * is in the next pulse frame (the link-loss failsafe: within its timeout plus one frame). A stop's safe
 * widths are on the timers before the state changes: a pulse frame that started between the two, with
 * the state changed first, drove a rotor at its old width while the board said DISARMED (the firmware's
 * fault campaign caught one at a run's final Disarm). */
static uint8_t enter_state(uint8_t next)
{
    uint8_t old = board.state;
    if (next == old)
        return old;
    if (!motors_enabled(next)) {
        hold_gimbals();
        stop_rotors();
        apply_outputs_for(next);
    }
    board.state = next;
    board.outputs_dirty = 1;
    return old;
}

static void report_state(uint8_t old, uint8_t next)
{
    if (next == old)
        return;
    char a[12], b[12];
    report_name(PSTR(BOARD_STATE_NAMES), old, a, sizeof a);
    report_name(PSTR(BOARD_STATE_NAMES), next, b, sizeof b);
    report_log(next == BOARD_STATE_FAILSAFE ? SEVERITY_WARNING : SEVERITY_INFO, LOG_CODE_STATE,
               PSTR("state %s -> %s"), a, b);
    report_heartbeat(clock_ms());
}

static uint8_t apply(uint8_t event)
{
    transition_t t = state_transition(board.state, event, power_ok());
    if (!t.refused)
        report_state(enter_state(t.state), t.state);
    return t.refused;
}

/*
 * The link watchdog decides in the main loop (on_link_lost: state, gimbal hold, reports), but a pass can
 * take a few ms when a Log, telemetry and a calibration conversion fall together, and the rotors must be
 * safe within the timeout plus one pulse frame. So the 1 kHz tick interrupt stops them itself, in the
 * tick the link times out: the rotor channels go to the safe pulse and are held there (pulses_hold)
 * until the main loop's next pass has made the change. It stands back while received bytes wait in the
 * UART ring (those are for the main loop to judge first), but only for LINK_GRACE_MS past the timeout:
 * under a flood bytes always wait, and a flood of frames the board discards is a silent link.
 */
static volatile uint8_t link_stopped;

/* A main-loop pass reads received bytes for at most RX_BUDGET_MS (process_rx): a host that writes faster
 * than the board can take (UART0 at 250 kbaud and up, flat out) must not keep the loop from its watchdog
 * check-in, the link watchdog, the reports and the outputs. What the ring cannot hold meanwhile is lost
 * and counted (the receive Log). Bytes left waiting when the budget ran out delay the link watchdog's
 * verdict by at most LINK_GRACE_MS (they may hold a frame received in time), never more. */
#define RX_BUDGET_MS 2u
#define LINK_GRACE_MS (2u * RX_BUDGET_MS)

static uint16_t rotor_channels(void)
{
    uint16_t mask = 0;
    for (uint8_t u = 0; u < board.cfg.n_units; u++)
        mask |= (uint16_t)(1u << (2u * u + 1u));
    return mask;
}

void app_tick(uint32_t now_ms)
{
    if (link_stopped || !board.session || board.link_lost || !board.have_rx || !motors_enabled(board.state))
        return;
    uint32_t quiet = now_ms - board.last_rx_ms;
    if (quiet < board.cfg.link_timeout_ms ||
        (quiet < (uint32_t)board.cfg.link_timeout_ms + LINK_GRACE_MS && port_rx_pending()))
        return;
    link_stopped = 1;
    pulses_hold(rotor_channels(), board.cfg.rotor_safe_us);
}

static void on_link_lost(uint32_t now)
{
    board.link_lost = 1;
    transition_t t = state_transition(board.state, EVENT_LINK_LOST, power_ok());
    uint8_t old = t.refused ? board.state : enter_state(t.state); /* outputs first, then the reports */
    pulses_release(rotor_channels()); /* the outputs are the main loop's again: safe, in FAILSAFE */
    link_stopped = 0;
    esc_cal_abort(ESC_CAL_ABORT_LINK_LOST, now); /* an ESC being taught: to minimum, before any report */
    report_log(SEVERITY_WARNING, LOG_CODE_LINK_LOST, PSTR("link lost: nothing valid for %u ms"),
               board.cfg.link_timeout_ms);
    if (!t.refused)
        report_state(old, t.state);
}

static void on_valid_rx(uint32_t now)
{
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { board.last_rx_ms = now; } /* app_tick reads it */
    board.have_rx = 1;
    if (board.link_lost) {
        board.link_lost = 0;
        report_log(SEVERITY_INFO, LOG_CODE_LINK_RESTORED, PSTR("link restored"));
    }
}

/* ------------------------------------------------------------------------------------------ commands */
static void on_hello(const hello_t *m, uint32_t now)
{
    if (m->protocol_version == PROTOCOL_VERSION && m->schema_hash == SCHEMA_HASH) {
        esc_cal_abort(ESC_CAL_ABORT_HELLO, now);
        board.mode = CONTROL_MODE_SETPOINT;
        answers_forget(&board.answers);
        reasm_forget(&board.reasm); /* a restarted host numbers its transfers from 1 again */
        apply(EVENT_HELLO);
        if (!board.session) {
            board.session = 1;
            periodic_start(&board.telemetry, board.cfg.telemetry_rate_hz, now, 1);
        }
    } else {
        report_log(SEVERITY_ERROR, LOG_CODE_HANDSHAKE,
                   PSTR("incompatible host: protocol %u schema 0x%08lx (board: %u, 0x%08lx)"),
                   m->protocol_version, (unsigned long)m->schema_hash, PROTOCOL_VERSION,
                   (unsigned long)SCHEMA_HASH);
    }
    report_hello_reply();
}

static uint8_t on_arm(void)
{
    if (board.state != BOARD_STATE_BOOT && !calibrations_complete())
        return NACK_REASON_BAD_CALIBRATION;
    if (esc_cal_active())
        return NACK_REASON_BUSY;
    uint8_t was = board.state;
    uint8_t refused = apply(EVENT_ARM);
    if (!refused) {
        board.shed_latched = 0;
        if (was != BOARD_STATE_ARMED)
            stop_rotors(); /* the safe pulse until the zero command is converted: never an old width */
        board.outputs_dirty = 1;
    }
    return refused;
}

static uint8_t on_set_mode(const set_mode_t *m)
{
    uint8_t refused = state_transition(board.state, EVENT_SET_MODE, power_ok()).refused;
    if (refused)
        return refused;
    if (m->mode != CONTROL_MODE_SETPOINT && m->mode != CONTROL_MODE_RAW_PULSES)
        return NACK_REASON_UNSUPPORTED; /* ESC_CALIBRATION is entered only by EscCalibrate */
    if (esc_cal_active())
        return NACK_REASON_BUSY;
    if (m->mode != board.mode) {
        board.mode = m->mode;
        char name[16];
        report_name(PSTR(CONTROL_MODE_NAMES), m->mode, name, sizeof name);
        report_log(SEVERITY_INFO, LOG_CODE_STATE, PSTR("mode %s"), name);
    }
    return 0;
}

static void on_setpoint(const actuator_setpoint_t *m)
{
    if (!motors_enabled(board.state) || board.mode != CONTROL_MODE_SETPOINT) {
        board.ignored_setpoints++;
        return;
    }
    if (m->units.count != board.cfg.n_units) {
        board.bad_setpoints++;
        report_log(SEVERITY_WARNING, LOG_CODE_BAD_COMMAND, PSTR("setpoint for %u units, board has %u"),
                   m->units.count, board.cfg.n_units);
        return;
    }
    board.setpoints++;
    board.gimbal_mode = m->gimbal_mode;
    for (uint8_t u = 0; u < board.cfg.n_units; u++) {
        board.gimbal_cmd[u] = m->units.items[u].gimbal;
        board.rotor_cmd[u] = m->units.items[u].rotor_speed;
    }
    board.outputs_dirty = 1;
}

static void on_raw_pulses(const raw_pulses_t *m)
{
    if (!motors_enabled(board.state) || board.mode != CONTROL_MODE_RAW_PULSES) {
        board.ignored_setpoints++;
        return;
    }
    if (m->pulses_us.count != board.n_channels) {
        board.bad_setpoints++;
        report_log(SEVERITY_WARNING, LOG_CODE_BAD_COMMAND, PSTR("raw pulses for %u channels, board has %u"),
                   m->pulses_us.count, board.n_channels);
        return;
    }
    board.setpoints++;
    memcpy(board.raw_cmd, m->pulses_us.items, board.n_channels * sizeof board.raw_cmd[0]);
    board.have_raw = 1;
    board.outputs_dirty = 1;
}

static uint8_t cal_refused(uint8_t unit, const char *why_flash, const char *detail)
{
    char why[48];
    strncpy_P(why, why_flash, sizeof why - 1);
    why[sizeof why - 1] = 0;
    report_log(SEVERITY_ERROR, LOG_CODE_CALIBRATION, PSTR("calibration upload for unit %u refused: %s%s"),
               unit, why, detail);
    return NACK_REASON_BAD_CALIBRATION;
}

static uint8_t on_calibration_data(const calibration_data_t *m)
{
    if (board.state != BOARD_STATE_DISARMED)
        return NACK_REASON_BAD_STATE;
    if (m->unit >= board.cfg.n_units)
        return NACK_REASON_OUT_OF_RANGE;
    /* A download of this unit's set re-reads it at every retry (no RAM for a copy): it must not change
     * under it, so its upload waits until the download has ended (docs/protocol.md). */
    if (board.download.active && board.download.unit == m->unit)
        return NACK_REASON_BUSY;
    board.reasm.max_len = storage_cal_room(m->unit);
    reasm_status_t st = reasm_feed(&board.reasm, m);
    static const char REASONS[] PROGMEM =
        "\0total_len larger than this board holds\0count does not fit total_len\0"
        "index not below count\0chunk of the wrong size\0"
        "fragment contradicts its transfer\0set CRC mismatch";
    if (st == REASM_PENDING)
        return 0;
    if (st != REASM_DONE) {
        const char *p = REASONS;
        for (uint8_t i = 0; i < (uint8_t)st - 1u; i++)
            while (pgm_read_byte(p++))
                ;
        return cal_refused(m->unit, p, "");
    }
    uint16_t len = board.reasm.done.total_len;
    uint8_t table, knot;
    cal_status_t cs = cal_validate(board.reasm.buf, len, &table, &knot);
    /* refused after reassembly: the set is forgotten, so the same set sent again is judged (and refused)
     * again, not acknowledged as a repeat of a set taken */
    if (cs != CAL_OK) {
        reasm_forget(&board.reasm);
        char detail[64];
        cal_status_text(cs, detail, sizeof detail);
        return cal_refused(m->unit, PSTR("invalid set: "), detail);
    }
    if (!storage_store_cal(m->unit, board.reasm.buf, len)) {
        reasm_forget(&board.reasm);
        return cal_refused(m->unit, PSTR("no room for the set in RAM"), "");
    }
    forget_conversions(m->unit);
    board.outputs_dirty = 1;
    report_log(SEVERITY_INFO, LOG_CODE_CALIBRATION, PSTR("calibration for unit %u stored (%u bytes)"),
               m->unit, len);
    return 0;
}

static uint8_t on_calibration_request(const calibration_request_t *m, uint32_t now)
{
    if (board.state == BOARD_STATE_BOOT)
        return NACK_REASON_BAD_STATE;
    if (m->unit >= board.cfg.n_units)
        return NACK_REASON_OUT_OF_RANGE;
    uint16_t len;
    const uint8_t *set = storage_cal(m->unit, &len);
    if (!set)
        return NACK_REASON_BAD_CALIBRATION;
    if (board.download.active)
        return NACK_REASON_BUSY;
    download_t *d = &board.download;
    d->active = 1;
    d->unit = m->unit;
    d->transfer_id = m->transfer_id;
    d->count = (uint8_t)((len + MAX_CALIBRATION_CHUNK - 1u) / MAX_CALIBRATION_CHUNK);
    d->set_crc = crc16_update(CRC16_INIT, set, len);
    for (uint8_t i = 0; i < d->count; i++) {
        d->tries[i] = 1;
        d->acked[i] = 0;
        d->retry_ms[i] = now + CAL_DOWNLOAD_RETRY_MS;
        report_cal_fragment(i, 0);
    }
    return 0;
}

static void on_answer(const frame_t *f)
{
    /* Ack and Nack share their first two fields (msg_id, seq). */
    const ack_t *a = &f->msg.ack;
    download_t *d = &board.download;
    uint8_t i = 0;
    while (d->active && i < d->count && !(d->seq[i] == a->seq && !d->acked[i]))
        i++;
    if (a->msg_id != MSG_CALIBRATION_DATA || !d->active || i == d->count) {
        board.ignored++;
        return;
    }
    if (f->msg_id == MSG_NACK) {
        d->active = 0;
        char name[20];
        report_name(PSTR(NACK_REASON_NAMES), f->msg.nack.reason, name, sizeof name);
        report_log(SEVERITY_WARNING, LOG_CODE_CALIBRATION, PSTR("host refused calibration fragment: %s"),
                   name);
        return;
    }
    d->acked[i] = 1;
    uint8_t all = 1;
    for (uint8_t k = 0; k < d->count; k++)
        all &= d->acked[k];
    if (all)
        d->active = 0;
}

static void retry_download(uint32_t now)
{
    download_t *d = &board.download;
    for (uint8_t i = 0; d->active && i < d->count; i++) {
        if (d->acked[i] || (int32_t)(now - d->retry_ms[i]) < 0)
            continue;
        if (d->tries[i] >= CAL_DOWNLOAD_TRIES) {
            d->active = 0;
            report_log(SEVERITY_ERROR, LOG_CODE_CALIBRATION,
                       PSTR("calibration download abandoned: no ACK after %u tries"), CAL_DOWNLOAD_TRIES);
            return;
        }
        d->tries[i]++;
        d->retry_ms[i] = now + CAL_DOWNLOAD_RETRY_MS;
        report_cal_fragment(i, 1);
    }
}

/* Run one command; 0 (accepted) or the NACK reason. */
static uint8_t execute(const frame_t *f, uint32_t now)
{
    switch (f->msg_id) {
    case MSG_ACTUATOR_SETPOINT:
        on_setpoint(&f->msg.actuator_setpoint);
        return 0;
    case MSG_RAW_PULSES:
        on_raw_pulses(&f->msg.raw_pulses);
        return 0;
    case MSG_HELLO:
        on_hello(&f->msg.hello, now);
        return 0;
    case MSG_ARM:
        return on_arm();
    case MSG_DISARM:
        esc_cal_abort(ESC_CAL_ABORT_DISARM, now);
        return apply(EVENT_DISARM);
    case MSG_ESC_CALIBRATE:
        return esc_cal_command(&f->msg.esc_calibrate, now);
    case MSG_SET_MODE:
        return on_set_mode(&f->msg.set_mode);
    case MSG_CALIBRATION_DATA:
        return on_calibration_data(&f->msg.calibration_data);
    case MSG_CALIBRATION_REQUEST:
        return on_calibration_request(&f->msg.calibration_request, now);
    case MSG_ACK:
    case MSG_NACK:
        on_answer(f);
        return 0;
    default: /* Heartbeat: feeding the link watchdog is all it does */
        return 0;
    }
}

static void handle_frame(const frame_t *f, uint32_t now)
{
    if (f->msg_id == MSG_HELLO_REPLY || f->msg_id == MSG_TELEMETRY || f->msg_id == MSG_LOG) {
        board.ignored++; /* board-to-host messages echoed back: not ours */
        return;
    }
    on_valid_rx(now);
    uint8_t reliable = (f->flags & FLAGS_ACK_REQUESTED) || msg_is_reliable(f->msg_id);
    uint8_t answer;
    if (reliable && answers_lookup(&board.answers, f, &answer)) {
        report_answer(f, answer);
        return;
    }
    answer = execute(f, now);
    if (reliable) {
        answers_remember(&board.answers, f, answer);
        report_answer(f, answer);
    }
}

/* Reads and handles received bytes for at most RX_BUDGET_MS; returns 1 when it stopped with bytes left. */
static uint8_t process_rx(uint32_t now)
{
    uint8_t b, more = 0;
    uint32_t start = clock_ms();
    while (port_read(&b)) {
        if (deframer_feed(&board.deframer, b, &board.frame) == DEFRAME_FRAME) {
            port_frame_valid(); /* "first": this frame's link becomes the link, before any answer */
            handle_frame(&board.frame, now);
        }
        if (clock_ms() - start >= RX_BUDGET_MS) {
            more = port_rx_pending();
            break;
        }
    }
    return more;
}

/* Received bytes lost since the last report, in a Log: at most one a heartbeat period (a flood loses bytes
 * in every pass, and a Log each pass would crowd the telemetry out of the transmit ring). */
static void report_rx_lost(void)
{
    uart_stats_t st;
    uart_stats(&st);
    if (st.rx_overflow != board.rx_lost.rx_overflow || st.line_errors != board.rx_lost.line_errors) {
        board.rx_lost = st;
        report_log(SEVERITY_WARNING, LOG_CODE_RX_OVERFLOW,
                   PSTR("receive: %lu bytes lost to a full buffer, %lu to line errors since boot"),
                   (unsigned long)st.rx_overflow, (unsigned long)st.line_errors);
    }
}

/* ------------------------------------------------------------------------------------------ power */
static void power_step(void)
{
    uint8_t old = board.power_state;
    float battery_v = board.power.battery_mv * 0.001f;
    uint8_t next = power_update(&board.pm, &board.power_params, battery_v);
    float filtered_v = board.pm.filtered_v_cell * (float)board.cfg.cells;
    board.conversion_v = (float)lrintf(filtered_v / VOLT_QUANTUM) * VOLT_QUANTUM;
    if (board.power.ubec_mv * 0.001f < board.cfg.brownout_release_v)
        next = POWER_STATE_BROWN_OUT; /* the rail is in the MCU's brown-out zone: reset imminent */
    board.power_state = next;
    if (next >= POWER_STATE_SHED && !board.shed_latched && motors_enabled(board.state)) /* BROWN_OUT too */
        board.shed_latched = 1;
    if (next != old) {
        board.outputs_dirty = 1;
        char a[12], b[12];
        report_name(PSTR(POWER_STATE_NAMES), old, a, sizeof a);
        report_name(PSTR(POWER_STATE_NAMES), next, b, sizeof b);
        uint16_t mv_cell = (uint16_t)lrintf(board.pm.filtered_v_cell * 1000.0f);
        report_log(next < old ? SEVERITY_INFO
                              : (next >= POWER_STATE_SHED ? SEVERITY_ERROR : SEVERITY_WARNING),
                   LOG_CODE_POWER, PSTR("power %s -> %s (battery %u mV, %u mV/cell, rail %u mV)"), a, b,
                   board.power.battery_mv, mv_cell, board.power.ubec_mv);
    }
    uint8_t over = board.power.ubec_ma * 0.001f > board.cfg.ubec_current_limit_a;
    if (over && !board.ubec_over)
        report_log(SEVERITY_WARNING, LOG_CODE_UBEC_OVERCURRENT, PSTR("UBEC over current: %u mA > %u mA"),
                   board.power.ubec_ma, (uint16_t)lrintf(board.cfg.ubec_current_limit_a * 1000.0f));
    board.ubec_over = over;
    /* after the power Logs, as the emulator (its PowerSupervisor reports, then the board aborts) */
    if (next >= POWER_STATE_SHED)
        esc_cal_abort(ESC_CAL_ABORT_POWER, clock_ms());
}

/* ------------------------------------------------------------------------------------------ boot, loop */
void app_boot(uint8_t reset_cause, config_status_t config, uint8_t config_problem)
{
    board_config_t *c = &board.cfg;
    uint32_t now = clock_ms();
    board.reset_cause = reset_cause;
    board.state = BOARD_STATE_BOOT;
    board.mode = CONTROL_MODE_SETPOINT;
    board.gimbal_mode = GIMBAL_MODE_RATE;
    board.n_channels = (uint8_t)(2u * c->n_units);
    deframer_init(&board.deframer);
    answers_forget(&board.answers);
    reasm_init(&board.reasm, CAL_MAX_SIZE);
    board.power_params.warn_v_cell = c->warn_v_cell;
    board.power_params.limit_v_cell = c->limit_v_cell;
    board.power_params.shed_v_cell = c->shed_v_cell;
    board.power_params.hysteresis_v_cell = c->hysteresis_v_cell;
    board.power_params.cells = c->cells;
    board.power_params.alpha = c->filter_time_constant_s > 0.0f
                                   ? 1.0f - expf(-c->power_update_period_s / c->filter_time_constant_s)
                                   : 1.0f;
    float frame_s = pulses_period_s();
    rotor_decay_up = expf(-frame_s / CFG_DEFAULT_MOTOR_TIME_CONSTANT_S);
    rotor_decay_down = expf(-frame_s / CFG_DEFAULT_MOTOR_COAST_TIME_CONSTANT_S);
    gimbal_decay = expf(-frame_s / CFG_DEFAULT_GIMBAL_TIME_CONSTANT_S);
    esc_cal_init();
    power_reset(&board.pm);
    power_step();
    periodic_start(&board.heartbeat, c->heartbeat_rate_hz, now, 0);
    board.next_power_ms = now + (uint32_t)lrintf(c->power_update_period_s * 1000.0f);
    while (convert_step())
        ;
    apply_outputs();

    char cause[12];
    report_name(PSTR(RESET_CAUSE_NAMES), reset_cause, cause, sizeof cause);
    report_log(SEVERITY_INFO, LOG_CODE_BOOT, PSTR("boot: reset cause %s"), cause);
    if (config != CONFIG_LOADED) {
        char what[32];
        config_problem_text(config_problem, what, sizeof what);
        report_log(config == CONFIG_ERASED ? SEVERITY_INFO : SEVERITY_ERROR, LOG_CODE_BOOT,
                   config == CONFIG_ERASED ? PSTR("no configuration in EEPROM: defaults in use")
                                           : PSTR("EEPROM configuration refused (%s): defaults in use"),
                   what);
    }
    for (uint8_t u = 0; u < c->n_units; u++)
        if (storage_cal_source(u) == CAL_SOURCE_MISSING)
            report_log(SEVERITY_ERROR, LOG_CODE_CALIBRATION,
                       PSTR("calibration of unit %u in EEPROM is damaged: upload one before arming"), u);
}

uint8_t app_poll(uint32_t now)
{
    port_poll(); /* USB: attach, enumeration, accessory handshake, bulk IN/OUT (bounded) */
    uint8_t more = process_rx(now);
    uint32_t quiet = now - board.last_rx_ms;
    if (board.session && !board.link_lost && board.have_rx &&
        (link_stopped || (quiet >= board.cfg.link_timeout_ms &&
                          (!more || quiet >= (uint32_t)board.cfg.link_timeout_ms + LINK_GRACE_MS))))
        on_link_lost(now);
    esc_cal_poll(now);
    if ((int32_t)(now - board.next_power_ms) >= 0) {
        board.next_power_ms += (uint32_t)lrintf(board.cfg.power_update_period_s * 1000.0f);
        if (adc_take(&board.power))
            power_step();
    }
    uint8_t busy = convert_step();
    uint8_t frame = pulses_frame_started();
    if (frame || busy || board.outputs_dirty)
        apply_outputs();
    if (frame)
        estimate_units(pulses_period_s());
    if (periodic_due(&board.telemetry, now)) {
        report_telemetry(now);
        esc_cal_report(now);
    }
    if (periodic_due(&board.heartbeat, now)) {
        report_heartbeat(now);
        report_rx_lost();
    }
    retry_download(now);
    storage_service(); /* one EEPROM byte when the EEPROM is ready (~3.3 ms a byte): no need to spin */
    return busy;
}
