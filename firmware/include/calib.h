/*
 * calib.h - one VSCMG unit's calibration set: validation and the pulse <-> throttle <-> speed and
 * pulse <-> gimbal rate/angle maps, a float32 port of protocol/calibration (cubic.py, maps.py, codec.py).
 *
 * A set is kept in its binary form (version 1, little-endian, what CalibrationData carries and EEPROM
 * holds) and read in place; nothing is copied into a parsed struct, so a unit costs its set's size in RAM.
 *
 *   0  "VC", version 1, flags 0          4  f32 esc.low_us, high_us, deadband_us, rotor.kv_rad_s_per_v,
 *   20 f32 gimbal_rate.hold_us          24  u8 knot counts n0..n3 (2..16 each)
 *   28 knots {f32 x, y, m} of four strictly monotone tables: 0 rotor curve (throttle -> fraction of KV*V),
 *      1 gimbal rate below the dead zone (us -> rad/s, ends at 0), 2 above it (starts at 0),
 *      3 gimbal angle (us -> rad);  then u16 CRC-16/CCITT-FALSE of everything before it.
 *
 * Sans-IO and portable (the tests run it on the host against the Python reference).
 */
#ifndef CALIB_H
#define CALIB_H

#include <stdint.h>

#define CAL_HEADER_SIZE 28u
#define CAL_KNOT_SIZE 12u
#define CAL_MAX_KNOTS 16u
#define CAL_TABLES 4u
#define CAL_MIN_SIZE (CAL_HEADER_SIZE + CAL_TABLES * 2u * CAL_KNOT_SIZE + 2u)
#define CAL_MAX_SIZE (CAL_HEADER_SIZE + CAL_TABLES * CAL_MAX_KNOTS * CAL_KNOT_SIZE + 2u)
#define CAL_MIN_SUPPLY_V 1.0f

enum { CAL_TABLE_ROTOR = 0, CAL_TABLE_RATE_LOWER = 1, CAL_TABLE_RATE_UPPER = 2, CAL_TABLE_ANGLE = 3 };
enum { CAL_CLAMP_NONE = 0, CAL_CLAMP_LOW = 1, CAL_CLAMP_HIGH = 2 };

/* Why a set was refused (the first problem found, in protocol/calibration/codec.py's order). */
typedef enum {
    CAL_OK = 0,
    CAL_TRUNCATED,     /* shorter than a header + CRC */
    CAL_BAD_MAGIC,     /* not "VC" */
    CAL_BAD_VERSION,   /* format version is not 1 */
    CAL_BAD_RESERVED,  /* flags not 0 */
    CAL_BAD_COUNT,     /* a table with fewer than 2 or more than 16 knots */
    CAL_BAD_LENGTH,    /* the length does not match the knot counts */
    CAL_BAD_CRC,       /* damaged */
    CAL_NOT_FINITE,    /* NaN or infinity */
    CAL_X_ORDER,       /* knot x not strictly increasing */
    CAL_FLAT,          /* first and last values equal */
    CAL_NOT_MONOTONE,  /* a value goes against the table's direction or repeats */
    CAL_BAD_SLOPE,     /* a knot slope outside 0..3x its intervals' secants */
    CAL_BAD_ESC,       /* endpoints outside 500..2500 us or not low < high, or a bad deadband */
    CAL_BAD_KV,        /* KV outside (0, 1e4] */
    CAL_BAD_CURVE,     /* throttle curve not from (0, 0) to (1, 1) */
    CAL_BAD_DEAD_ZONE, /* rate tables not meeting 0 at the dead zone, or turning opposite ways */
    CAL_BAD_HOLD,      /* hold pulse outside the dead zone */
    CAL_BAD_PULSE,     /* a gimbal map's pulse (hold, or a rate or angle knot) outside 500..2500 us */
    CAL_ERRORS
} cal_status_t;

typedef struct {
    float value;
    uint8_t clamp; /* CAL_CLAMP_*: the input was outside the map's range (value is the range's end) */
} cal_conv_t;

/* Check a whole set. On failure *table is the table (CAL_TABLE_*, 0xFF: header) and *knot the knot. */
cal_status_t cal_validate(const uint8_t *set, uint16_t len, uint8_t *table, uint8_t *knot);
/* Length of the set whose header is at `set` (valid counts assumed), or 0 if the header is malformed. */
uint16_t cal_set_length(const uint8_t *header);
/* A short English description of a status, for Log text, into `out` (room for `n` bytes). */
void cal_status_text(cal_status_t status, char *out, unsigned n);

/* The maps (the set must have passed cal_validate). Inputs must be finite. */
cal_conv_t cal_rotor_pulse_us(const uint8_t *set, float speed_rad_s, float battery_v);
cal_conv_t cal_rotor_speed(const uint8_t *set, float pulse_us, float battery_v);
cal_conv_t cal_gimbal_pulse_us(const uint8_t *set, float value, uint8_t gimbal_mode);
cal_conv_t cal_gimbal_value(const uint8_t *set, float pulse_us, uint8_t gimbal_mode);
/* ESC endpoints (us): minimum throttle and full throttle. */
float cal_esc_low_us(const uint8_t *set);
float cal_esc_high_us(const uint8_t *set);

#endif /* CALIB_H */
