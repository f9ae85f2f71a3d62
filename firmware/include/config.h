/*
 * config.h - the board configuration (firmware_sim.board.config.BoardConfig's fields the firmware uses), read
 * from the EEPROM block at boot (layout generated into board_gen.h from firmware_sim/avr/eeprom.py).
 * Without a valid block the defaults of BoardConfig, compiled in, are used.
 */
#ifndef CONFIG_H
#define CONFIG_H

#include <stdint.h>

#include "board_gen.h"

typedef struct {
    uint8_t n_units, ppm, cells, esc_supply_switch;
    float frame_rate_hz, telemetry_rate_hz, heartbeat_rate_hz;
    uint16_t link_timeout_ms, mcu_watchdog_ms, rotor_safe_us;
    float battery_resistance_ohm;
    float warn_v_cell, limit_v_cell, shed_v_cell, hysteresis_v_cell, limit_throttle;
    float brownout_release_v, filter_time_constant_s, power_update_period_s, ubec_current_limit_a;
    uint32_t baud;
    uint8_t link; /* LINK_UART, LINK_USB or LINK_FIRST (board_gen.h): where the host's protocol runs */
    char serial[SERIAL_LEN + 1];
} board_config_t;

typedef enum {
    CONFIG_LOADED = 0, /* the EEPROM block is valid and in use */
    CONFIG_ERASED,     /* no block: defaults */
    CONFIG_DAMAGED,    /* CRC, magic or version wrong: defaults */
    CONFIG_INVALID     /* a value out of range (config_problem names it): defaults */
} config_status_t;

void config_defaults(board_config_t *cfg);
#define CONFIG_OK_FIELD 0u

/* Parse and check a block of EEPROM_CONFIG_SIZE bytes; on any problem *cfg holds the defaults and
 * *problem names what was wrong (config_problem_text). */
config_status_t config_parse(const uint8_t *block, board_config_t *cfg, uint8_t *problem);
void config_problem_text(uint8_t problem, char *out, unsigned n);
/* UART0's divisor (UBRR + 1, double speed) for `baud`: the whole one nearest to the rate. */
uint16_t config_uart_divisor(uint32_t baud);

#endif /* CONFIG_H */
