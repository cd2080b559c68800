/* A C renderer's use of gs-cache, checked: make a cache from points, read its levels, train
 * them towards known targets, save, load and free. Exits 0 only if every check holds.
 * Built and run by crates/gs-cache/tests/c_abi.rs:
 *   cc -std=c11 -Wall -Wextra -Werror -I include c/drive_cache.c libgs_cache.a -lm -lpthread -ldl
 *   ./drive_cache OUTPUT_DIR */
#include "gs_cache.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static int failures = 0;

#define CHECK(cond, ...)                                                                  \
    do {                                                                                  \
        if (!(cond)) {                                                                    \
            fprintf(stderr, "FAIL %s:%d: %s: ", __FILE__, __LINE__, #cond);              \
            fprintf(stderr, __VA_ARGS__);                                                 \
            fprintf(stderr, " (last error: %s)\n", gs_cache_last_error());                \
            failures++;                                                                   \
        }                                                                                 \
    } while (0)

/* Deterministic points in the cube [-0.5, 0.5]^3 (a 32-bit LCG: no libc rand). */
static float next_unit(uint32_t *state) {
    *state = *state * 1664525u + 1013904223u;
    return (float)(*state >> 8) / 16777216.0f;
}

int main(int argc, char **argv) {
    const char *out_dir = argc > 1 ? argv[1] : "drive_cache_out";
    enum { COUNT = 4096, SIZE = 32, FRAMES = 60 };

    GsCacheConfig config = gs_cache_default_config();
    CHECK(config.levels == 3, "default levels %u", config.levels);
    CHECK(fabsf(config.c - 0.5f) < 1e-7f, "C %g", config.c);
    CHECK(fabsf(config.lr_color - 0.1f) < 1e-7f, "colour rate %g", config.lr_color);

    /* Algorithm 1: C = 0.5 times the luminance of a grey albedo product 0.8 is 0.4. */
    const float grey[3] = {0.8f, 0.8f, 0.8f};
    float q = gs_cache_continue_probability(&config, grey);
    CHECK(fabsf(q - 0.4f) < 1e-6f, "continue probability %g, expected 0.4", q);

    static float positions[3 * COUNT], albedo[3 * COUNT];
    uint32_t rng = 12345u;
    for (int i = 0; i < 3 * COUNT; i++) {
        positions[i] = next_unit(&rng) - 0.5f;
        albedo[i] = 0.8f;
    }
    config.levels = 2;
    config.lr_color = 0.25f; /* fast, to see training move the colours in 60 frames */
    GsCacheHandle *cache = gs_cache_new(positions, albedo, COUNT, &config);
    CHECK(cache != NULL, "gs_cache_new failed");
    if (cache == NULL) return 1;
    CHECK(gs_cache_levels(cache) == 2, "levels %u", gs_cache_levels(cache));
    CHECK(gs_cache_gaussian_count(cache, 0) == COUNT, "level 0 has %zu", gs_cache_gaussian_count(cache, 0));
    CHECK(gs_cache_gaussian_count(cache, 1) == COUNT / 2, "level 1 has %zu", gs_cache_gaussian_count(cache, 1));

    /* Reading before any frame gives NULL, and training is refused. */
    CHECK(gs_cache_level_image(cache, 0) == NULL, "an image before the first frame");
    CHECK(gs_cache_train(cache, NULL) == GS_CACHE_STATUS_NO_FRAME, "train before a frame");

    /* A camera too large to allocate for is refused with a status, not an abort of this program. */
    GsCacheCamera huge = {{0.0f, 0.0f, -2.5f}, {0.0f, 0.0f, 0.0f}, {0.0f, 1.0f, 0.0f}, 40.0f, 100000, 100000};
    CHECK(gs_cache_begin_frame(cache, &huge) == GS_CACHE_STATUS_INVALID_ARGUMENT, "a 100000x100000 camera");
    CHECK(strstr(gs_cache_last_error(), "too large") != NULL, "message: %s", gs_cache_last_error());
    CHECK(gs_cache_level_image(cache, 0) == NULL, "a refused frame left an image");

    GsCacheCamera camera = {{0.0f, 0.0f, -2.5f}, {0.0f, 0.0f, 0.0f}, {0.0f, 1.0f, 0.0f}, 40.0f, SIZE, SIZE};
    CHECK(gs_cache_begin_frame(cache, &camera) == GS_CACHE_STATUS_OK, "begin_frame");
    const int centre = (SIZE / 2) * SIZE + SIZE / 2;
    const float *image = gs_cache_level_image(cache, 0);
    CHECK(image != NULL, "no level 0 image");
    if (image == NULL) return 1;
    /* The cube's albedo-coloured Gaussians cover the centre: a grey between 0.3 and 0.8. */
    float start = image[3 * centre];
    CHECK(start > 0.3f && start <= 0.8f + 1e-4f, "initial centre value %g", start);
    CHECK(image[3 * centre] == image[3 * centre + 1] && image[3 * centre + 1] == image[3 * centre + 2],
          "grey albedo gave a colour (%g %g %g)", image[3 * centre], image[3 * centre + 1], image[3 * centre + 2]);
    CHECK(gs_cache_level_image(cache, 2) == NULL, "level 2 does not exist");

    /* A sample out of range is refused with a message. */
    const float two[3] = {2.0f, 2.0f, 2.0f}, one[3] = {1.0f, 1.0f, 1.0f};
    CHECK(gs_cache_add_sample(cache, 0, SIZE * SIZE, two) == GS_CACHE_STATUS_INVALID_ARGUMENT, "pixel out of range");
    CHECK(strlen(gs_cache_last_error()) > 0, "no message for the bad sample");

    /* Train towards 2.0 (level 0) and 1.0 (level 1) over the central 16x16 pixels. */
    double first_mse = -1.0, last_mse = -1.0;
    for (int frame = 0; frame < FRAMES; frame++) {
        if (frame > 0) CHECK(gs_cache_begin_frame(cache, &camera) == GS_CACHE_STATUS_OK, "begin_frame %d", frame);
        for (int y = 8; y < 24; y++)
            for (int x = 8; x < 24; x++) {
                gs_cache_add_sample(cache, 0, (uint32_t)(y * SIZE + x), two);
                gs_cache_add_sample(cache, 1, (uint32_t)(y * SIZE + x), one);
            }
        GsCacheReport report;
        CHECK(gs_cache_train(cache, &report) == GS_CACHE_STATUS_OK, "train %d", frame);
        CHECK(report.levels_trained == 2, "levels trained %u", report.levels_trained);
        CHECK(isfinite(report.first_level_mse) && report.first_level_mse >= 0.0, "mse %g", report.first_level_mse);
        if (frame == 0) first_mse = report.first_level_mse;
        last_mse = report.first_level_mse;
    }
    CHECK(gs_cache_begin_frame(cache, &camera) == GS_CACHE_STATUS_OK, "final begin_frame");
    float end = gs_cache_level_image(cache, 0)[3 * centre];
    printf("level 0 centre: %.4f -> %.4f (target 2); mse %.4f -> %.4f\n", start, end, first_mse, last_mse);
    CHECK(last_mse < 0.25 * first_mse, "training did not lower the error: %g -> %g", first_mse, last_mse);
    CHECK(end > start + 0.5f && end < 2.5f, "centre moved from %g to %g", start, end);

    /* Save, load into a second handle, and compare what both draw. */
    CHECK(gs_cache_save(cache, out_dir) == GS_CACHE_STATUS_OK, "save to %s", out_dir);
    GsCacheHandle *loaded = gs_cache_load(out_dir, &config);
    CHECK(loaded != NULL, "load from %s", out_dir);
    if (loaded != NULL) {
        CHECK(gs_cache_levels(loaded) == 2, "loaded levels %u", gs_cache_levels(loaded));
        CHECK(gs_cache_begin_frame(loaded, &camera) == GS_CACHE_STATUS_OK, "loaded begin_frame");
        float again = gs_cache_level_image(loaded, 0)[3 * centre];
        CHECK(fabsf(again - end) < 1e-3f * end, "loaded cache draws %g, saved drew %g", again, end);
    }
    CHECK(gs_cache_load("/nonexistent/gs-cache", &config) == NULL, "loading a missing directory");

    /* The unbiased estimator through the C ABI. A renderer's paths are simulated: each has
     * throughput 1 at level 0's vertex and gathers R = 2u from there on (u uniform: mean 1).
     * The cache holds 2 there (it was trained towards 2), far from R's mean, and the estimate
     * C + (R - C) / q (going on) or C (stopping) must still average 1. First, statistics that
     * make stopping pay (the tail is 90% of the work and nearly noiseless against the cache)
     * so that q falls below 1. */
    GsCacheConfig ub_config = config;
    ub_config.unbiased = true;
    GsCacheHandle *ub = gs_cache_load(out_dir, &ub_config);
    CHECK(ub != NULL, "load the unbiased cache");
    if (ub != NULL) {
        float cached[3], q_used = 0.0f, w[3] = {1.0f, 1.0f, 1.0f};
        CHECK(gs_cache_begin_frame(ub, &camera) == GS_CACHE_STATUS_OK, "unbiased begin_frame");
        CHECK(gs_cache_control_variate(ub, 0, (uint32_t)centre, 7u, w, cached, &q_used) == -1 && q_used == 1.0f,
              "before any statistics every path goes on (q %g)", q_used);
        for (int frame = 0; frame < 4; frame++) {
            if (frame > 0) CHECK(gs_cache_begin_frame(ub, &camera) == GS_CACHE_STATUS_OK, "begin_frame %d", frame);
            for (uint32_t p = 0; p < SIZE * SIZE; p++) {
                GsCacheLevelRead reads[2] = {{1.0f, true, 1.0f, 1e-4f, 9.0f}, {0.0f, false, 0.0f, 0.0f, 0.0f}};
                float estimate = 0.5f + next_unit(&rng);
                CHECK(gs_cache_add_path_statistics(ub, p, estimate, 10.0f, 2, reads) == GS_CACHE_STATUS_OK,
                      "statistics at %u", p);
            }
            CHECK(gs_cache_train(ub, NULL) == GS_CACHE_STATUS_OK, "unbiased train %d", frame);
        }
        CHECK(gs_cache_add_path_statistics(ub, 0, 1.0f, 1.0f, 3, NULL) != GS_CACHE_STATUS_OK, "NULL reads");
        CHECK(gs_cache_begin_frame(ub, &camera) == GS_CACHE_STATUS_OK, "unbiased begin_frame");
        enum { PATHS = 200000 };
        double sum = 0.0, sum2 = 0.0;
        int stops = 0;
        for (uint64_t key = 0; key < PATHS; key++) {
            float r = 2.0f * next_unit(&rng), q = 1.0f;
            int decision = gs_cache_control_variate(ub, 0, (uint32_t)centre, key, w, cached, &q);
            double c = cached[0], e;
            if (decision == 1) e = c + (r - c) / q;
            else if (decision == 0) e = c, stops++;
            else e = r;
            if (key == 0) q_used = q;
            sum += e;
            sum2 += e * e;
        }
        double mean = sum / PATHS, se = sqrt((sum2 / PATHS - mean * mean) / PATHS);
        printf("unbiased cache through C: cached %.3f, q %.3f, %d of %d paths stopped, mean %.4f (se %.4f), expected 1\n",
               cached[0], q_used, stops, PATHS, mean, se);
        CHECK(q_used < 1.0f && stops > PATHS / 10, "q %g, %d stops: the estimator was not exercised", q_used, stops);
        CHECK(fabs(mean - 1.0) < 4.42 * se, "mean %g, expected 1 within 4.42 standard errors (%g)", mean, se);
        gs_cache_free(ub);
    }

    gs_cache_free(loaded);
    gs_cache_free(cache);
    gs_cache_free(NULL);
    if (failures == 0) printf("drive_cache: all checks passed\n");
    return failures == 0 ? 0 : 1;
}
