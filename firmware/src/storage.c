/* storage.c - EEPROM configuration and calibration sets (see storage.h). */
#include "storage.h"

#include <avr/eeprom.h>
#include <string.h>

#include "calib.h"
#include "crc16.h"
#include "flash.h"
#include "protocol_gen.h"

static uint8_t pool[CAL_POOL_SIZE];
static uint16_t offsets[MAX_HW_UNITS], lengths[MAX_HW_UNITS];
static uint8_t sources[MAX_HW_UNITS];
static uint8_t units;
static uint16_t slot_size;
static uint8_t dirty;       /* units whose set must be written to EEPROM */
static uint8_t writing;     /* unit being written (valid while write_step is set) */
static uint16_t write_step; /* 0: idle; else 1 + the step of the write sequence */

config_status_t storage_load_config(board_config_t *cfg, uint8_t *problem)
{
    uint8_t block[EEPROM_CONFIG_SIZE];
    eeprom_read_block(block, (const void *)0, sizeof block);
    return config_parse(block, cfg, problem);
}

static uint16_t slot_address(uint8_t unit)
{
    return (uint16_t)(EEPROM_CAL_BASE + (uint16_t)unit * slot_size);
}

static uint16_t pool_used(void)
{
    uint16_t used = 0;
    for (uint8_t u = 0; u < units; u++)
        used = (uint16_t)(used + lengths[u]);
    return used;
}

/* Remove a unit's set from the pool (the sets after it move down). */
static void pool_remove(uint8_t unit)
{
    uint16_t start = offsets[unit], n = lengths[unit];
    if (!n)
        return;
    uint16_t end = pool_used();
    memmove(pool + start, pool + start + n, end - start - n);
    for (uint8_t u = 0; u < units; u++)
        if (lengths[u] && offsets[u] > start)
            offsets[u] = (uint16_t)(offsets[u] - n);
    lengths[unit] = 0;
}

/* Append room for a unit's set; NULL if the pool is full. */
static uint8_t *pool_append(uint8_t unit, uint16_t n)
{
    uint16_t used = pool_used();
    if ((uint32_t)used + n > CAL_POOL_SIZE)
        return 0;
    offsets[unit] = used;
    lengths[unit] = n;
    return pool + used;
}

void storage_load_calibrations(uint8_t n_units)
{
    units = n_units > MAX_HW_UNITS ? MAX_HW_UNITS : n_units;
    slot_size = (uint16_t)((EEPROM_SIZE - EEPROM_CAL_BASE) / units);
    if (slot_size > CAL_MAX_SIZE)
        slot_size = CAL_MAX_SIZE;
    for (uint8_t u = 0; u < units; u++) {
        uint16_t addr = slot_address(u);
        uint8_t header[CAL_HEADER_SIZE];
        eeprom_read_block(header, (const void *)(uintptr_t)addr, sizeof header);
        sources[u] = CAL_SOURCE_MISSING;
        lengths[u] = 0;
        if (header[0] == 0xFF) {
            uint8_t *dst = pool_append(u, DEFAULT_CALIBRATION_LEN);
            if (dst) {
                flash_read(dst, DEFAULT_CALIBRATION, DEFAULT_CALIBRATION_LEN);
                sources[u] = CAL_SOURCE_DEFAULT;
            }
            continue;
        }
        uint16_t n = cal_set_length(header);
        uint8_t *dst = n && n <= slot_size ? pool_append(u, n) : 0;
        if (!dst)
            continue;
        eeprom_read_block(dst, (const void *)(uintptr_t)addr, n);
        if (cal_validate(dst, n, 0, 0) == CAL_OK)
            sources[u] = CAL_SOURCE_EEPROM;
        else
            lengths[u] = 0; /* damaged: give the room back */
    }
}

cal_source_t storage_cal_source(uint8_t unit)
{
    return unit < units ? (cal_source_t)sources[unit] : CAL_SOURCE_MISSING;
}

const uint8_t *storage_cal(uint8_t unit, uint16_t *len)
{
    if (unit >= units || sources[unit] == CAL_SOURCE_MISSING)
        return 0;
    if (len)
        *len = lengths[unit];
    return pool + offsets[unit];
}

uint16_t storage_cal_room(uint8_t unit)
{
    if (unit >= units)
        return 0;
    uint16_t room = (uint16_t)(CAL_POOL_SIZE - pool_used() + lengths[unit]);
    return room < slot_size ? room : slot_size;
}

uint8_t storage_store_cal(uint8_t unit, const uint8_t *set, uint16_t len)
{
    if (unit >= units || len > storage_cal_room(unit))
        return 0;
    pool_remove(unit);
    uint8_t *dst = pool_append(unit, len);
    memcpy(dst, set, len);
    sources[unit] = CAL_SOURCE_UPLOADED;
    dirty |= (uint8_t)(1u << unit);
    if (write_step && writing == unit)
        write_step = 0; /* restart that unit's write with the new set */
    return 1;
}

/* Write sequence of a set of n bytes: bytes 0 and 1 (the magic) to 0x00 (invalid), bytes 2..n-1,
 * then byte 1 and byte 0 of the set (valid again, only once everything else is in place). */
uint8_t storage_service(void)
{
    if (!write_step) {
        if (!dirty)
            return 0;
        for (writing = 0; !(dirty & (1u << writing)); writing++)
            ;
        dirty &= (uint8_t) ~(1u << writing);
        write_step = 1;
    }
    if (!eeprom_is_ready())
        return 1;
    uint16_t n = lengths[writing], step = (uint16_t)(write_step - 1u);
    const uint8_t *set = pool + offsets[writing];
    uint16_t addr = slot_address(writing);
    if (step < 2)
        eeprom_update_byte((uint8_t *)(uintptr_t)(addr + step), 0x00);
    else if (step < n)
        eeprom_update_byte((uint8_t *)(uintptr_t)(addr + step), set[step]);
    else if (step == n)
        eeprom_update_byte((uint8_t *)(uintptr_t)(addr + 1u), set[1]);
    else
        eeprom_update_byte((uint8_t *)(uintptr_t)addr, set[0]);
    write_step = step > n ? 0 : (uint16_t)(write_step + 1u);
    return write_step != 0 || dirty;
}

/* ------------------------------------------------------------------------------------------ boot counter */
#define BOOT_COUNT_ERASED 0xFFFFFFFFul

static uint32_t *boot_slot(uint8_t i)
{
    return (uint32_t *)(uintptr_t)(EEPROM_BOOT_COUNT_BASE + 4u * i);
}

/* The counter moved on and written: the largest count in the slots (erased ones hold none) plus one, into
 * slot count % EEPROM_BOOT_COUNT_SLOTS, so each slot's cells wear at a quarter of the boots' rate. A count
 * that would read as erased starts the counter again from 0 (after 2^32 boots, or a damaged slot). */
static uint32_t boot_count_next(void)
{
    uint32_t count = 0;
    for (uint8_t i = 0; i < EEPROM_BOOT_COUNT_SLOTS; i++) {
        uint32_t c = eeprom_read_dword(boot_slot(i));
        if (c != BOOT_COUNT_ERASED && c > count)
            count = c;
    }
    count++;
    if (count == BOOT_COUNT_ERASED) {
        count = 0;
        for (uint8_t i = 0; i < EEPROM_BOOT_COUNT_SLOTS; i++)
            eeprom_update_dword(boot_slot(i), 0);
    }
    eeprom_update_dword(boot_slot((uint8_t)(count % EEPROM_BOOT_COUNT_SLOTS)), count);
    return count;
}

uint32_t storage_new_boot_id(const char *serial)
{
    uint16_t mix = crc16_update(0xFFFFu, (const uint8_t *)serial, (uint16_t)strnlen(serial, SERIAL_LEN));
    uint32_t id;
    do
        id = boot_count_next() ^ ((uint32_t)mix << 16);
    while (!id); /* 0 says "no boot id": the one count that gives it is skipped */
    return id;
}
