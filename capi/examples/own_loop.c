/*
 * Plugging the GPM projection into your own particle loop, from C.
 *
 * The same loop as gpm's Rust example examples/own_loop.rs, number for number: a Taylor-Green
 * vortex on a 40 x 40 lattice in the periodic unit square, nu = 0.01, the incremental scheme, a
 * linear drag force -0.1 u of the user's own, 20 steps of dt = 0.002. The particles, the
 * forces and the advection are the caller's; gpm predicts, projects on the moved configuration
 * and reports. Prints the same table as `cargo run --release --example own_loop`.
 *
 *   cc -O2 -Iinclude capi/examples/own_loop.c -Ltarget/release -lgpm_capi -lm -o own_loop
 *   LD_LIBRARY_PATH=target/release ./own_loop [--out DIR]
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gpm.h"

#define N 40
#define STEPS 20
#define NP (N * N)

static const double PI = 3.14159265358979323846;

/* Rust's {:>width.3e}: 1.307e-1 (no '+', no leading zeros in the exponent) */
static void rust_e(char *buf, size_t len, double v) {
    char tmp[32];
    snprintf(tmp, sizeof tmp, "%.3e", v);
    char *e = strchr(tmp, 'e');
    if (e == NULL) {
        snprintf(buf, len, "%s", tmp);
        return;
    }
    *e = '\0';
    snprintf(buf, len, "%se%d", tmp, atoi(e + 1));
}

/* Fails loudly with gpm's message, the particle and the parameter it names. */
static int check(GpmStatus st, const char *what) {
    if (st == GPM_STATUS_OK) return 0;
    const char *param = gpm_last_error_parameter();
    fprintf(stderr, "error: %s: %s: %s (particle %lld, parameter %s)\n", what,
            gpm_status_name(st), gpm_last_error_message(), (long long)gpm_last_error_particle(),
            param ? param : "-");
    return 1;
}

/* the user's own periodic wrap into [0, 1): Rust's rem_euclid */
static double wrap01(double v) {
    double r = fmod(v, 1.0);
    if (r < 0.0) r += 1.0;
    return r >= 1.0 ? 0.0 : r;
}

int main(int argc, char **argv) {
    const char *out_dir = NULL;
    for (int i = 1; i < argc; i++) {
        if (strcmp(argv[i], "--out") == 0 && i + 1 < argc) {
            out_dir = argv[++i];
        } else {
            fprintf(stderr, "unknown argument '%s' (usage: own_loop [--out DIR])\n", argv[i]);
            return 2;
        }
    }
    const double dx = 1.0 / N, dt = 0.002, drag = 0.1;
    static double x[NP][2], u[NP][2], u_star[NP][2], forces[NP][2];
    static GpmReport reports[STEPS];

    /* the user's particles: the cell-centred lattice, last axis fastest */
    for (int i = 0, k = 0; i < N; i++) {
        for (int j = 0; j < N; j++, k++) {
            x[k][0] = 0.0 + (i + 0.5) * dx;
            x[k][1] = 0.0 + (j + 0.5) * dx;
            double s2x = sin(2.0 * PI * x[k][0]), c2x = cos(2.0 * PI * x[k][0]);
            double s2y = sin(2.0 * PI * x[k][1]), c2y = cos(2.0 * PI * x[k][1]);
            u[k][0] = -c2x * s2y;
            u[k][1] = s2x * c2y;
        }
    }

    GpmSettings s;
    gpm_settings_default(&s);
    s.dim = 2;
    s.h = 3.0 * dx;
    s.skin = 0.3 * s.h; /* a skin, so that most updates only re-measure pairs */
    s.weight = GPM_WEIGHT_WENDLAND_C2;
    s.boundary = GPM_BOUNDARY_KIND_PERIODIC;
    s.lo[0] = s.lo[1] = 0.0;
    s.hi[0] = s.hi[1] = 1.0;
    s.nu = 0.01;
    s.scheme = GPM_SCHEME_INCREMENTAL;

    GpmSystem *sys = NULL;
    if (check(gpm_system_new(&s, NP, &x[0][0], &u[0][0], NULL, NULL, &sys), "gpm_system_new"))
        return 1;

    GpmRecorder *rec = NULL;
    char path[4096];
    if (out_dir != NULL) {
        snprintf(path, sizeof path, "%s/run.mcap", out_dir);
        const char *config = "{\"n\": 40, \"steps\": 20, \"dt\": 0.002, \"drag\": 0.1}";
        if (check(gpm_recorder_new(path, GPM_RECORD_LEVEL_FULL, 5, config, &rec),
                  "gpm_recorder_new"))
            return 1;
    }

    int rc = 0;
    for (int k = 1; k <= STEPS && rc == 0; k++) {
        /* capture the projection's inputs only where the recorder takes a snapshot */
        int snapshot = 0;
        if (rec != NULL) rc |= check(gpm_recorder_wants_snapshot(rec, k, &snapshot), "snapshot");
        rc |= check(gpm_system_set_capture(sys, snapshot), "capture");
        rc |= check(gpm_system_update_neighbors(sys, NULL), "update_neighbors");
        /* the user's own force: linear drag */
        rc |= check(gpm_system_get_velocities(sys, &u[0][0], NP), "get_velocities");
        for (int i = 0; i < NP; i++) {
            forces[i][0] = -drag * u[i][0];
            forces[i][1] = -drag * u[i][1];
        }
        if (rc) break;
        rc |= check(gpm_system_predict(sys, dt, &forces[0][0], &u_star[0][0], NP), "predict");
        if (rc) break;
        /* the user's own advection with the predictor velocity, then the periodic wrap */
        for (int i = 0; i < NP; i++) {
            x[i][0] = wrap01(x[i][0] + dt * u_star[i][0]);
            x[i][1] = wrap01(x[i][1] + dt * u_star[i][1]);
        }
        rc |= check(gpm_system_set_positions(sys, &x[0][0], NP), "set_positions");
        rc |= check(gpm_system_update_neighbors(sys, NULL), "update_neighbors");
        if (rc) break;
        rc |= check(gpm_system_project(sys, dt, &u_star[0][0], NP, &reports[k - 1]), "project");
        if (rec != NULL && rc == 0)
            rc |= check(gpm_recorder_record(rec, sys, k, k * dt), "record");
    }
    if (rec != NULL) {
        uint64_t steps = 0;
        if (rc == 0) {
            rc |= check(gpm_recorder_finish(rec, &steps), "gpm_recorder_finish");
            if (rc == 0) printf("recorded %llu steps to %s\n", (unsigned long long)steps, path);
        } else {
            gpm_recorder_free(rec);
        }
    }
    gpm_system_free(sys);
    if (rc) return 1;

    printf("%4s %12s %12s %8s %10s %10s\n", "step", "div before", "div after", "c0", "ratio",
           "KE");
    for (int k = 0; k < STEPS; k++) {
        char a[48], b[48], c[48];
        rust_e(a, sizeof a, reports[k].div_before);
        rust_e(b, sizeof b, reports[k].div_after);
        rust_e(c, sizeof c, reports[k].stability_ratio);
        printf("%4d %12s %12s %8.4f %10s %10.5f\n", k + 1, a, b, reports[k].c0, c,
               reports[k].kinetic_energy);
    }
    return 0;
}
