/*
 * power.h - the staged power manager (the C twin of firmware_sim/board/power_models.py: PowerManager).
 *
 * The battery voltage per cell is low-pass filtered (time constant filter_time_constant_s) and compared
 * with the staged thresholds warn > limit > shed (volts per cell); each stage is entered below its level
 * and left only hysteresis_v_cell above it. BROWN_OUT is decided by the caller from the UBEC rail.
 * Sans-IO and portable.
 */
#ifndef POWER_H
#define POWER_H

#include <stdint.h>

typedef struct {
    float warn_v_cell, limit_v_cell, shed_v_cell, hysteresis_v_cell;
    float alpha; /* filter gain per update: 1 - exp(-update_period / time_constant) (1: no filter) */
    uint8_t cells;
} power_params_t;

typedef struct {
    float filtered_v_cell;
    uint8_t primed; /* filtered_v_cell holds a value */
    uint8_t stage;  /* POWER_STATE_NORMAL..SHED */
} power_manager_t;

void power_reset(power_manager_t *pm);
/* One update with a new battery reading (volts); returns the stage. The first update after a reset
 * takes the reading as it is. */
uint8_t power_update(power_manager_t *pm, const power_params_t *p, float battery_v);
/* Volts of a full LiPo cell at rest: the top of the open-circuit curve (BoardConfig's ocv_curve). The
 * configuration refuses a warn threshold whose clearing level (warn + hysteresis) reaches it. */
float power_full_cell_v(void);
/* State of charge 0..1 of a LiPo cell at rest at `v_cell` volts (the open-circuit curve, interpolated). */
float power_soc(float v_cell);

#endif /* POWER_H */
