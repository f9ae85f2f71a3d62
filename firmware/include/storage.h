/*
 * storage.h - the EEPROM and the calibration sets in RAM.
 *
 * Every unit's calibration set lives in RAM (a pool shared by the units, each set as many bytes as it
 * has) and in its EEPROM slot (board_gen.h; firmware_sim/avr/eeprom.py). At boot an erased slot means
 * the default set (compiled in), a valid one is loaded, a damaged one leaves the unit without
 * calibration (ARM is then refused). An uploaded set takes effect at once and is written to EEPROM in
 * the background, one byte per ~3.3 ms EEPROM write, never blocking the main loop; the slot is first
 * marked invalid and its magic written last, so a reset in the middle leaves "no calibration", never a
 * half-written set that looks valid.
 */
#ifndef STORAGE_H
#define STORAGE_H

#include <stdint.h>

#include "config.h"

/* Six sets of the default 414 bytes (2484), three of the largest 798 (2394). 2544, not 2560: the boot id
 * (app.h board.boot_id, and HelloReply's in the two message buffers) took 12 bytes of RAM where the size
 * test had 3 left (README.md); a smaller UART transmit ring lost a phone-detach run's FAILSAFE heartbeat
 * (tests/test_firmware_usb_world.py). */
#define CAL_POOL_SIZE 2544u

typedef enum {
    CAL_SOURCE_MISSING = 0, /* damaged in EEPROM, or never loaded: no calibration */
    CAL_SOURCE_DEFAULT,     /* erased slot: the compiled-in default set */
    CAL_SOURCE_EEPROM,      /* the set stored in EEPROM */
    CAL_SOURCE_UPLOADED     /* uploaded since boot (being or having been written to EEPROM) */
} cal_source_t;

/* Read the configuration block (status as config_parse). */
config_status_t storage_load_config(board_config_t *cfg, uint8_t *problem);
/* Load every unit's set (after the configuration). */
void storage_load_calibrations(uint8_t n_units);
cal_source_t storage_cal_source(uint8_t unit);
/* The unit's set (NULL if missing) and its length. */
const uint8_t *storage_cal(uint8_t unit, uint16_t *len);
/* The largest set an upload may bring for `unit` (its EEPROM slot, and what the RAM pool can hold). */
uint16_t storage_cal_room(uint8_t unit);
/* Install a validated set for `unit`: 1, or 0 if it does not fit (the old set stays). */
uint8_t storage_store_cal(uint8_t unit, const uint8_t *set, uint16_t len);
/* Background EEPROM writes: call from the main loop. 1 while writes are pending. */
uint8_t storage_service(void);
/* This boot's id (HelloReply.boot_id, Heartbeat.boot_id), nonzero: the EEPROM boot counter moved on by
 * one (written before it returns: ~3.4 ms an EEPROM byte, blocking; call it once, early in the boot, with
 * interrupts off) and mixed with the board's serial (firmware_sim/avr/eeprom.py boot_id). */
uint32_t storage_new_boot_id(const char *serial);

#endif /* STORAGE_H */
