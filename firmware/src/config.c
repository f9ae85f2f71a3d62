/* config.c - the EEPROM configuration block (see config.h). Portable. */
#include "config.h"

#include <math.h>
#include <string.h>

#include "adc.h"
#include "crc16.h"
#include "flash.h"
#include "power.h"
#include "protocol_gen.h"
#include "pulses.h"
#include "wire.h"

enum {
    BAD_BLOCK = 1, /* magic, version or CRC */
    BAD_N_UNITS,
    BAD_FRAME_RATE_HZ,
    BAD_TELEMETRY_RATE_HZ,
    BAD_HEARTBEAT_RATE_HZ,
    BAD_LINK_TIMEOUT_S,
    BAD_MCU_WATCHDOG_S,
    BAD_ROTOR_SAFE_US,
    BAD_PPM,
    BAD_CELLS,
    BAD_BATTERY_RESISTANCE_OHM,
    BAD_WARN_V_CELL,
    BAD_HYSTERESIS_V_CELL,
    BAD_LIMIT_THROTTLE,
    BAD_BROWNOUT_RELEASE_V,
    BAD_FILTER_TIME_CONSTANT_S,
    BAD_POWER_UPDATE_PERIOD_S,
    BAD_UBEC_CURRENT_LIMIT_A,
    BAD_ESC_SUPPLY_SWITCH,
    BAD_BAUD,
    BAD_LINK,
};

/* Names of what config_parse found wrong, in the order above (index = *problem). */
static const char PROBLEMS[] FLASH = "none\0"
                                     "magic, version or CRC\0"
                                     "n_units\0"
                                     "frame_rate_hz\0"
                                     "telemetry_rate_hz\0"
                                     "heartbeat_rate_hz\0"
                                     "link_timeout_s\0"
                                     "mcu_watchdog_s\0"
                                     "rotor_safe_us\0"
                                     "ppm\0"
                                     "cells\0"
                                     "battery_resistance_ohm\0"
                                     "warn/limit/shed_v_cell\0"
                                     "hysteresis_v_cell\0"
                                     "limit_throttle\0"
                                     "brownout_release_v\0"
                                     "filter_time_constant_s\0"
                                     "power_update_period_s\0"
                                     "ubec_current_limit_a\0"
                                     "esc_supply_switch\0"
                                     "baud\0"
                                     "link\0";

void config_problem_text(uint8_t problem, char *out, unsigned n) { flash_pick(PROBLEMS, problem, out, n); }

static float f32(const uint8_t *p)
{
    float v;
    memcpy(&v, p, 4);
    return v;
}

/* lo <= v <= hi, false for NaN. */
static int within(float v, float lo, float hi) { return v >= lo && v <= hi; }

/* Whether `s` seconds is a whole number of milliseconds (to 1 us): the power manager runs on the
 * millisecond clock (app.c's next_power_ms) while its filter gain is worked out from `s` itself, so 1.5 ms
 * ran every 2 ms with the gain of 1.5 (eeprom.py's _check_power_period refuses the same). */
static int whole_ms(float s)
{
    float ms = s * 1000.0f;
    return fabsf(ms - (float)lrintf(ms)) <= 1e-3f; /* within() has put it in 1..100 ms first */
}

static const uint8_t DEFAULTS[EEPROM_CONFIG_SIZE] FLASH = DEFAULT_CONFIG_BLOCK;

uint16_t config_uart_divisor(uint32_t baud)
{
    return (uint16_t)((UART_CLOCK_HZ + 4UL * baud) / (8UL * baud)); /* double speed, to the nearest */
}

/* Whether UART0 makes `baud` (9600..1000000) within UART_MAX_BAUD_ERROR_PERMILLE: a whole divisor puts
 * 921600 at 1 Mbaud (+8.5 %), a link the host reads only garbage from (eeprom.py, MAX_BAUD_ERROR_PERMILLE). */
static int baud_made(uint32_t baud)
{
    uint32_t made = UART_CLOCK_HZ / (8UL * config_uart_divisor(baud));
    uint32_t off = made > baud ? made - baud : baud - made;
    return off * 1000UL <= baud * UART_MAX_BAUD_ERROR_PERMILLE;
}

/* Read and check a block: CONFIG_OK_FIELD and *cfg filled, or the problem (a BAD_* value). */
static uint8_t parse(const uint8_t *b, board_config_t *cfg);

/* BoardConfig's defaults: the generated default block, through the same parser. */
void config_defaults(board_config_t *cfg)
{
    uint8_t block[EEPROM_CONFIG_SIZE];
    flash_read(block, DEFAULTS, sizeof block);
    parse(block, cfg);
}

config_status_t config_parse(const uint8_t *b, board_config_t *cfg, uint8_t *problem)
{
    uint8_t erased = 1;
    for (uint8_t i = 0; i < EEPROM_CONFIG_SIZE; i++)
        erased &= b[i] == 0xFF;
    *problem = erased ? CONFIG_OK_FIELD : parse(b, cfg);
    if (!erased && *problem == CONFIG_OK_FIELD)
        return CONFIG_LOADED;
    config_defaults(cfg);
    return erased ? CONFIG_ERASED : (*problem == BAD_BLOCK ? CONFIG_DAMAGED : CONFIG_INVALID);
}

static uint8_t parse(const uint8_t *b, board_config_t *cfg)
{
    if (wire_get_u16(b + CFG_OFF_MAGIC) != EEPROM_CONFIG_MAGIC ||
        b[CFG_OFF_VERSION] != EEPROM_CONFIG_VERSION ||
        crc16_update(CRC16_INIT, b, CFG_OFF_CRC) != wire_get_u16(b + CFG_OFF_CRC))
        return BAD_BLOCK;
    board_config_t c;
    uint8_t problem = CONFIG_OK_FIELD;
    c.n_units = b[CFG_OFF_N_UNITS];
    c.ppm = b[CFG_OFF_PPM];
    c.cells = b[CFG_OFF_CELLS];
    c.esc_supply_switch = b[CFG_OFF_ESC_SUPPLY_SWITCH];
    c.frame_rate_hz = f32(b + CFG_OFF_FRAME_RATE_HZ);
    c.telemetry_rate_hz = f32(b + CFG_OFF_TELEMETRY_RATE_HZ);
    c.heartbeat_rate_hz = f32(b + CFG_OFF_HEARTBEAT_RATE_HZ);
    float link = f32(b + CFG_OFF_LINK_TIMEOUT_S), wdt = f32(b + CFG_OFF_MCU_WATCHDOG_S);
    c.rotor_safe_us = wire_get_u16(b + CFG_OFF_ROTOR_SAFE_US);
    c.battery_resistance_ohm = f32(b + CFG_OFF_BATTERY_RESISTANCE_OHM);
    c.warn_v_cell = f32(b + CFG_OFF_WARN_V_CELL);
    c.limit_v_cell = f32(b + CFG_OFF_LIMIT_V_CELL);
    c.shed_v_cell = f32(b + CFG_OFF_SHED_V_CELL);
    c.hysteresis_v_cell = f32(b + CFG_OFF_HYSTERESIS_V_CELL);
    c.limit_throttle = f32(b + CFG_OFF_LIMIT_THROTTLE);
    c.brownout_release_v = f32(b + CFG_OFF_BROWNOUT_RELEASE_V);
    c.filter_time_constant_s = f32(b + CFG_OFF_FILTER_TIME_CONSTANT_S);
    c.power_update_period_s = f32(b + CFG_OFF_POWER_UPDATE_PERIOD_S);
    c.ubec_current_limit_a = f32(b + CFG_OFF_UBEC_CURRENT_LIMIT_A);
    c.baud = wire_get_u32(b + CFG_OFF_BAUD);
    c.link = b[CFG_OFF_LINK];
    uint8_t n = 0;
    while (n < SERIAL_LEN && b[CFG_OFF_SERIAL + n] && b[CFG_OFF_SERIAL + n] < 0x80)
        n++;
    memcpy(c.serial, b + CFG_OFF_SERIAL, n);
    c.serial[n] = 0;
    /* the same limits as BoardConfig.validate() (and the hardware's) */
    if (c.n_units < 1 || c.n_units > MAX_HW_UNITS)
        problem = BAD_N_UNITS;
    else if (!within(c.frame_rate_hz, 50.0f, 490.0f))
        problem = BAD_FRAME_RATE_HZ;
    else if (!within(c.telemetry_rate_hz, 0.1f, 1000.0f))
        problem = BAD_TELEMETRY_RATE_HZ;
    else if (!within(c.heartbeat_rate_hz, 0.1f, 1000.0f))
        problem = BAD_HEARTBEAT_RATE_HZ;
    else if (!within(link, 0.01f, 60.0f))
        problem = BAD_LINK_TIMEOUT_S;
    else if (!within(wdt, 0.1f, 8.0f)) /* MCU_WATCHDOG_MIN_S: the longest main-loop pass fits, 3 times */
        problem = BAD_MCU_WATCHDOG_S;
    else if (c.rotor_safe_us < PULSE_MIN_US || c.rotor_safe_us > PULSE_MAX_US)
        problem = BAD_ROTOR_SAFE_US;
    /* the safe pulse goes out unclamped (pulses_hold): one past the frame's end is no pulse at all, a
     * constant high (pulses.h, PULSE_GAP_TICKS; pulses_init's period) */
    else if ((long)c.rotor_safe_us * 2L + (long)PULSE_GAP_TICKS > lrintf(2e6f / c.frame_rate_hz))
        problem = BAD_ROTOR_SAFE_US;
    else if (c.ppm > 1 || (c.ppm && c.n_units > 4))
        problem = BAD_PPM;
    /* One cell (4.2 V full) cannot hold the rail up (BoardConfig); a pack full above the battery ADC's top
     * reading (5 cells or more) reads low, its stage wrong from power-on (eeprom.py's check_hardware). */
    else if (c.cells < 2 || (float)c.cells * power_full_cell_v() > (float)ADC_BATTERY_MAX_MV * 0.001f)
        problem = BAD_CELLS;
    else if (!within(c.battery_resistance_ohm, 0.0f, 10.0f))
        problem = BAD_BATTERY_RESISTANCE_OHM;
    else if (!(c.warn_v_cell > c.limit_v_cell && c.limit_v_cell > c.shed_v_cell && c.shed_v_cell > 0.0f))
        problem = BAD_WARN_V_CELL;
    else if (!within(c.hysteresis_v_cell, 0.0f, 1.0f))
        problem = BAD_HYSTERESIS_V_CELL;
    /* a stage is left hysteresis above its level: at or above a full cell one entered never clears, and
     * thresholds above it shed a full pack's load from power-on (BoardConfig.validate alike) */
    else if (!(c.warn_v_cell + c.hysteresis_v_cell < power_full_cell_v()))
        problem = BAD_WARN_V_CELL;
    else if (!within(c.limit_throttle, 0.0f, 1.0f))
        problem = BAD_LIMIT_THROTTLE;
    /* BROWN_OUT is left when the measured rail reaches the release level (app.c's power_step): one the
     * rail's ADC cannot report, or at or above a full pack (the rail is the pack less the UBEC's dropout),
     * held the board in BROWN_OUT for good, every Arm NACKed POWER (BoardConfig.validate refuses these). */
    else if (!(c.brownout_release_v > 0.0f && (float)ADC_UBEC_MAX_MV * 0.001f >= c.brownout_release_v &&
               c.brownout_release_v < (float)c.cells * power_full_cell_v()))
        problem = BAD_BROWNOUT_RELEASE_V;
    else if (!within(c.filter_time_constant_s, 0.0f, 10.0f))
        problem = BAD_FILTER_TIME_CONSTANT_S;
    else if (!within(c.power_update_period_s, 0.001f, 0.1f) || !whole_ms(c.power_update_period_s))
        problem = BAD_POWER_UPDATE_PERIOD_S;
    else if (!within(c.ubec_current_limit_a, 0.01f, 100.0f))
        problem = BAD_UBEC_CURRENT_LIMIT_A;
    else if (c.esc_supply_switch > 1)
        problem = BAD_ESC_SUPPLY_SWITCH;
    else if (c.baud < 9600 || c.baud > 1000000 || !baud_made(c.baud))
        problem = BAD_BAUD;
    else if (c.link >= LINK_COUNT)
        problem = BAD_LINK;
    if (problem)
        return problem;
    c.link_timeout_ms = (uint16_t)lrintf(link * 1000.0f);
    c.mcu_watchdog_ms = (uint16_t)lrintf(wdt * 1000.0f);
    *cfg = c;
    return CONFIG_OK_FIELD;
}
