/*
 * state.h - the board's state machine as a pure transition function (firmware_sim/board/state.py).
 *
 *   reset -> BOOT --Hello--> DISARMED <--Disarm/Hello-- ARMED, FAILSAFE
 *            DISARMED --Arm--> ARMED --link lost--> FAILSAFE --Arm--> ARMED
 * Arm is refused in BOOT (BAD_STATE) and while load is shed (POWER); Disarm and SetMode are refused in
 * BOOT; SetMode only in DISARMED. Motors move only in ARMED.
 */
#ifndef STATE_H
#define STATE_H

#include <stdint.h>

#include "protocol_gen.h"

enum { EVENT_RESET, EVENT_HELLO, EVENT_ARM, EVENT_DISARM, EVENT_SET_MODE, EVENT_LINK_LOST };

typedef struct {
    uint8_t state;   /* the new state */
    uint8_t refused; /* 0: accepted, else the NACK_REASON_* */
} transition_t;

transition_t state_transition(uint8_t state, uint8_t event, uint8_t power_ok);

/* Whether setpoints may move the motors in `state`. */
static inline uint8_t motors_enabled(uint8_t state) { return state == BOARD_STATE_ARMED; }

#endif /* STATE_H */
