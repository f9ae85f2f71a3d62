/* config.c - the EEPROM configuration block (see config.h). Portable. */
#include "config.h"

#include <math.h>
#include <string.h>

#include "crc16.h"
#include "flash.h"
#include "protocol_gen.h"
#include "wire.h"

void config_defaults(board_config_t *cfg)
{
    memset(cfg, 0, sizeof *cfg);
    cfg->n_units = CFG_DEFAULT_N_UNITS;
    cfg->ppm = CFG_DEFAULT_PPM;
    cfg->cells = CFG_DEFAULT_CELLS;
    cfg->frame_rate_hz = CFG_DEFAULT_FRAME_RATE_HZ;
    cfg->telemetry_rate_hz = CFG_DEFAULT_TELEMETRY_RATE_HZ;
    cfg->heartbeat_rate_hz = CFG_DEFAULT_HEARTBEAT_RATE_HZ;
    cfg->link_timeout_ms = (uint16_t)lrintf(CFG_DEFAULT_LINK_TIMEOUT_S * 1000.0f);
    cfg->mcu_watchdog_ms = (uint16_t)lrintf(CFG_DEFAULT_MCU_WATCHDOG_S * 1000.0f);
    cfg->rotor_safe_us = CFG_DEFAULT_ROTOR_SAFE_US;
    cfg->battery_resistance_ohm = CFG_DEFAULT_BATTERY_RESISTANCE_OHM;
    cfg->warn_v_cell = CFG_DEFAULT_WARN_V_CELL;
    cfg->limit_v_cell = CFG_DEFAULT_LIMIT_V_CELL;
    cfg->shed_v_cell = CFG_DEFAULT_SHED_V_CELL;
    cfg->hysteresis_v_cell = CFG_DEFAULT_HYSTERESIS_V_CELL;
    cfg->limit_throttle = CFG_DEFAULT_LIMIT_THROTTLE;
    cfg->brownout_release_v = CFG_DEFAULT_BROWNOUT_RELEASE_V;
    cfg->filter_time_constant_s = CFG_DEFAULT_FILTER_TIME_CONSTANT_S;
    cfg->power_update_period_s = CFG_DEFAULT_POWER_UPDATE_PERIOD_S;
    cfg->ubec_current_limit_a = CFG_DEFAULT_UBEC_CURRENT_LIMIT_A;
    cfg->baud = CFG_DEFAULT_BAUD;
    strcpy(cfg->serial, IDENTITY_SERIAL);
}

/* Names of what config_parse found wrong (index = *problem). */
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
                                      "baud\0";

void config_problem_text(uint8_t problem, char *out, unsigned n) { flash_pick(PROBLEMS, problem, out, n); }

static float f32(const uint8_t *p)
{
    float v;
    memcpy(&v, p, 4);
    return v;
}

/* lo <= v <= hi, false for NaN. */
static int within(float v, float lo, float hi) { return v >= lo && v <= hi; }

config_status_t config_parse(const uint8_t *b, board_config_t *cfg, uint8_t *problem)
{
    config_defaults(cfg);
    *problem = CONFIG_OK_FIELD;
    uint8_t erased = 1;
    for (uint8_t i = 0; i < EEPROM_CONFIG_SIZE; i++)
        erased &= b[i] == 0xFF;
    if (erased)
        return CONFIG_ERASED;
    if (wire_get_u16(b + CFG_OFF_MAGIC) != EEPROM_CONFIG_MAGIC || b[CFG_OFF_VERSION] != EEPROM_CONFIG_VERSION ||
        crc16_update(CRC16_INIT, b, CFG_OFF_CRC) != wire_get_u16(b + CFG_OFF_CRC)) {
        *problem = 1;
        return CONFIG_DAMAGED;
    }
    board_config_t c = *cfg;
    c.n_units = b[CFG_OFF_N_UNITS];
    c.ppm = b[CFG_OFF_PPM];
    c.cells = b[CFG_OFF_CELLS];
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
    uint8_t n = 0;
    while (n < SERIAL_LEN && b[CFG_OFF_SERIAL + n] && b[CFG_OFF_SERIAL + n] < 0x80)
        n++;
    memcpy(c.serial, b + CFG_OFF_SERIAL, n);
    c.serial[n] = 0;
    /* the same limits as BoardConfig.validate() (and the hardware's) */
    if (c.n_units < 1 || c.n_units > MAX_HW_UNITS)
        *problem = 2;
    else if (!within(c.frame_rate_hz, 50.0f, 490.0f))
        *problem = 3;
    else if (!within(c.telemetry_rate_hz, 0.1f, 1000.0f))
        *problem = 4;
    else if (!within(c.heartbeat_rate_hz, 0.1f, 1000.0f))
        *problem = 5;
    else if (!within(link, 0.01f, 60.0f))
        *problem = 6;
    else if (!within(wdt, 0.015f, 8.0f))
        *problem = 7;
    else if (c.rotor_safe_us < PULSE_MIN_US || c.rotor_safe_us > PULSE_MAX_US)
        *problem = 8;
    else if (c.ppm > 1 || (c.ppm && c.n_units > 4))
        *problem = 9;
    else if (c.cells < 1 || c.cells > 12)
        *problem = 10;
    else if (!within(c.battery_resistance_ohm, 0.0f, 10.0f))
        *problem = 11;
    else if (!(c.warn_v_cell > c.limit_v_cell && c.limit_v_cell > c.shed_v_cell && c.shed_v_cell > 0.0f))
        *problem = 12;
    else if (!within(c.hysteresis_v_cell, 0.0f, 1.0f))
        *problem = 13;
    else if (!within(c.limit_throttle, 0.0f, 1.0f))
        *problem = 14;
    else if (!within(c.brownout_release_v, 0.0f, 24.0f))
        *problem = 15;
    else if (!within(c.filter_time_constant_s, 0.0f, 10.0f))
        *problem = 16;
    else if (!within(c.power_update_period_s, 0.001f, 0.1f))
        *problem = 17;
    else if (!within(c.ubec_current_limit_a, 0.01f, 100.0f))
        *problem = 18;
    else if (c.baud < 9600 || c.baud > 1000000)
        *problem = 19;
    if (*problem)
        return CONFIG_INVALID;
    c.link_timeout_ms = (uint16_t)lrintf(link * 1000.0f);
    c.mcu_watchdog_ms = (uint16_t)lrintf(wdt * 1000.0f);
    *cfg = c;
    return CONFIG_LOADED;
}
