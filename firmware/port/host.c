/* The host port: the C module as a shared library for the simulation (asm_module/c_module.py loads it with ctypes).
 * Python owns the memory (asm_host_size bytes) and supplies the frame sender and the joint as callbacks; time comes
 * with every call, so a simulated clock drives the module as it drives the Python runtime. */
#include <stddef.h>

#include "asm/module.h"

typedef int (*send_fn)(void *ctx, uint32_t id, const uint8_t *data, uint8_t dlc);
typedef void (*command_fn)(void *ctx, float degrees);
typedef void (*relax_fn)(void *ctx);
typedef void (*read_fn)(void *ctx, float *angle, float *torque, uint8_t *contact);

size_t asm_host_size(void) { return sizeof(struct asm_module); }

void asm_host_init(struct asm_module *m, const char *name, uint8_t node_id, send_fn send, command_fn command,
                   relax_fn relax, read_fn read, float hardware_min, float hardware_max, uint32_t now_ms)
{
    struct asm_port port = {send, NULL, 0};
    struct asm_joint_port joint = {command, relax, read, NULL};
    asm_module_init(m, name, node_id, &port, &joint, hardware_min, hardware_max, now_ms);
}

void asm_host_frame(struct asm_module *m, uint32_t id, const uint8_t *data, uint8_t dlc, uint32_t now_ms)
{
    asm_node_frame(&m->node, id, data, dlc, now_ms);
}

/* 1 (once) when the program now waits on other neighbours: the acceptance filters must change (asm_host_watched). */
int asm_host_watch_changed(struct asm_module *m)
{
    int changed = m->gait.run.watch_changed;
    m->gait.run.watch_changed = 0;
    return changed;
}

/* The node IDs whose gait.state publications the program waits on, into ``ids``; how many. */
int asm_host_watched(const struct asm_module *m, uint8_t *ids) { return asm_program_watched(m, ids); }

/* A request from the module itself (asm_node_local) at ``now_ms``: how a simulation loads a C module's gait. */
int asm_host_local(struct asm_module *m, const uint8_t *message, size_t length, uint32_t now_ms)
{
    m->node.now_ms = now_ms;
    return asm_node_local(&m->node, message, length);
}

void asm_host_tick(struct asm_module *m, uint32_t now_ms) { asm_module_tick(m, now_ms); }
void asm_host_leave(struct asm_module *m) { asm_node_leave(&m->node); }
int asm_host_latched(const struct asm_module *m) { return m->node.estop; }
uint32_t asm_host_done(const struct asm_module *m) { return m->gait.done_v; } /* gait.done's last firing, 0: none */
int asm_host_gait_running(const struct asm_module *m) { return m->gait.service.running; }
uint32_t asm_host_served(const struct asm_module *m) { return m->node.served; }
uint32_t asm_host_dropped(const struct asm_module *m) { return m->node.dropped + m->node.rx.dropped; }
float asm_host_angle(const struct asm_module *m) { return m->angle_v; }
/* The ID of the object called ``name`` (the same on every module), 0 if there is none. */
int asm_host_object_id(struct asm_module *m, const char *name)
{
    struct asm_object *o = asm_node_find(&m->node, name);
    return o != NULL ? o->id : 0;
}
float asm_host_goal(const struct asm_module *m) { return m->goal_v; }
/* When the gait last started (its ramp's start), in the milliseconds the caller gives; 0 before any start. */
uint32_t asm_host_gait_started_ms(const struct asm_module *m) { return m->gait.ramp_start_ms; }
