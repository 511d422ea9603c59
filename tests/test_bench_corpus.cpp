// `refocus bench corpus` on a tiny corpus of two synth clips (one dev, one val): the table and
// its CSV, the split filter, and bad corpora refused naming the file.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <sstream>

#include "io/image_file.h"
#include "test_util.h"
#include "util/fs.h"

using namespace refocus;
using namespace refocus::test;

namespace {

std::vector<std::vector<std::string>> read_csv(const fs::path& path) {
    std::ifstream in(path);
    REQUIRE(in.good());
    std::vector<std::vector<std::string>> rows;
    for (std::string line; std::getline(in, line);) {
        if (line.empty()) continue;
        std::vector<std::string> f;
        std::stringstream ss(line);
        for (std::string x; std::getline(ss, x, ',');) f.push_back(x);
        if (line.back() == ',') f.push_back("");
        rows.push_back(f);
    }
    return rows;
}

// Mean over frames of the PSNR of input_%04d.png against sharp_%04d.png, from the 8-bit codes
// (OpenCV, not the engine's readers).
double input_psnr_from_pngs(const fs::path& clip, int frames) {
    double sum = 0;
    for (int t = 0; t < frames; ++t) {
        char in[32], gt[32];
        std::snprintf(in, sizeof in, "input_%04d.png", t);
        std::snprintf(gt, sizeof gt, "sharp_%04d.png", t);
        const cv::Mat a = cv::imread((clip / in).string(), cv::IMREAD_COLOR);
        const cv::Mat b = cv::imread((clip / gt).string(), cv::IMREAD_COLOR);
        REQUIRE(!a.empty());
        REQUIRE(a.size() == b.size());
        double se = 0;
        for (size_t i = 0; i < a.total() * 3; ++i) {
            const double d = double(a.data[i]) - b.data[i];
            se += d * d;
        }
        sum += 10 * std::log10(255.0 * 255.0 / (se / (a.total() * 3)));
    }
    return sum / frames;
}

// The largest channel's |mean(input) − mean(sharp)| over the frames, 8-bit codes from the PNGs.
double input_shift_from_pngs(const fs::path& clip, int frames) {
    double sum[2][3] = {};
    size_t n = 0;
    for (int t = 0; t < frames; ++t)
        for (int k = 0; k < 2; ++k) {
            char name[32];
            std::snprintf(name, sizeof name, k ? "sharp_%04d.png" : "input_%04d.png", t);
            const cv::Mat m = cv::imread((clip / name).string(), cv::IMREAD_COLOR);  // BGR
            REQUIRE(!m.empty());
            for (size_t i = 0; i < m.total() * 3; ++i) sum[k][2 - i % 3] += m.data[i];
            if (k == 0) n += m.total();
        }
    double worst = 0;
    for (int c = 0; c < 3; ++c) worst = std::max(worst, std::abs(sum[0][c] - sum[1][c]) / n);
    return worst;
}

void make_clip(const fs::path& dir, const std::string& scene, const std::string& split) {
    RunResult r = cli("synth --scene " + scene + " -o '" + dir.string() +
                      "' --size 64x36 --frames 6 --seed 3");
    INFO(r.output);
    REQUIRE(r.code == 0);
    nlohmann::json j = nlohmann::json::parse(read_text_file(dir / "clip.json"));
    j["split"] = split;
    write_file_atomic(dir / "clip.json", j.dump(2));
}

}  // namespace

TEST_CASE("bench corpus: one row per clip and a mean, the CSV, --split, bad corpora refused") {
    const fs::path root = scratch_dir("bench_corpus"), corpus = root / "corpus";
    make_clip(corpus / "rack", "rack", "dev");
    make_clip(corpus / "tripod", "tripod", "val");
    const fs::path csv = root / "all.csv";
    RunResult r = cli("bench corpus '" + corpus.string() + "' --split all --iters 20 --csv '" +
                      csv.string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    CHECK(r.output.find("[1/2] rack") != std::string::npos);  // progress, per clip
    CHECK(r.output.find("[2/2] tripod") != std::string::npos);
    CHECK(r.output.find("targets met by") != std::string::npos);

    auto rows = read_csv(csv);
    REQUIRE(rows.size() == 4);                   // header, rack, tripod, mean
    const std::vector<std::string> h = rows[0];  // a copy: rows is read again below
    auto col = [&](const std::string& name) {
        const auto it = std::find(h.begin(), h.end(), name);
        REQUIRE(it != h.end());
        return static_cast<size_t>(it - h.begin());
    };
    CHECK(rows[1][0] == "rack");
    CHECK(rows[1][1] == "dev");
    CHECK(rows[2][0] == "tripod");
    CHECK(rows[2][1] == "val");
    CHECK(rows[3][0] == "mean");
    for (size_t i = 1; i < rows.size(); ++i) {
        REQUIRE(rows[i].size() == h.size());
        for (const char* name :
             {"frames", "frames_done", "in_psnr", "out_psnr", "gain_psnr", "in_ssim", "out_ssim",
              "in_tpsnr", "out_tpsnr", "worst_gain", "in_psnr_inside", "out_psnr_inside",
              "in_psnr_outside", "out_psnr_outside", "in_colour_shift", "out_colour_shift", "steps",
              "fit_s", "target_gain"}) {
            INFO(name << " in row " << i);
            CHECK(std::isfinite(std::stod(rows[i][col(name)])));
        }
    }
    // The yardstick (#51): the measured noise, the oracle blend at least
    // as good as the better of input and model, and the radius error against coc_%04d.exr.
    for (size_t i = 1; i < 3; ++i) {
        for (const char* name : {"noise_levels", "model_gain", "oracle_gain", "radius_err_med_out",
                                 "radius_err_p90_out"}) {
            INFO(name << " in row " << i);
            CHECK(std::isfinite(std::stod(rows[i][col(name)])));
        }
        CHECK(std::stod(rows[i][col("noise_levels")]) >= 0);  // 64x36: texture reads as noise
        CHECK(std::stod(rows[i][col("oracle_gain")]) >=
              std::max(0.0, std::stod(rows[i][col("model_gain")])) - 0.1);
        CHECK(std::stod(rows[i][col("radius_err_p90_out")]) >=
              std::stod(rows[i][col("radius_err_med_out")]));
    }
    CHECK(r.output.find("captured") != std::string::npos);
    CHECK(std::stoi(rows[1][col("steps")]) == 20);
    CHECK(std::stoi(rows[1][col("frames")]) == 6);
    CHECK(std::stoi(rows[1][col("worst_frame")]) >= 0);
    // The input's PSNR against the PNGs, computed here from their 8-bit codes.
    CHECK(std::abs(std::stod(rows[1][col("in_psnr")]) - input_psnr_from_pngs(corpus / "rack", 6)) <
          0.01);
    // The colour shift of the input, computed here from the same PNGs.
    CHECK(std::stod(rows[1][col("in_colour_shift")]) ==
          doctest::Approx(input_shift_from_pngs(corpus / "rack", 6)).epsilon(1e-3));
    // The mean row: the clips' mean.
    CHECK(std::stod(rows[3][col("in_psnr")]) ==
          doctest::Approx(
              (std::stod(rows[1][col("in_psnr")]) + std::stod(rows[2][col("in_psnr")])) / 2)
              .epsilon(1e-4));

    // --split val: only the val clip; the CSV goes to <dir>/bench_val_fast.csv by default.
    // Without its alpha frames the clip has no inside/outside split: empty CSV fields.
    for (int t = 0; t < 6; ++t) {
        char name[32];
        std::snprintf(name, sizeof name, "alpha_%04d.png", t);
        fs::remove(corpus / "tripod" / name);
    }
    r = cli("bench corpus '" + corpus.string() + "' --split val --iters 3");
    INFO(r.output);
    REQUIRE(r.code == 0);
    CHECK(r.output.find("[1/1] tripod") != std::string::npos);
    CHECK(r.output.find("rack (dev") == std::string::npos);  // neither fitted
    CHECK(r.output.find("\nrack ") == std::string::npos);    // nor in the table
    rows = read_csv(corpus / "bench_val_fast.csv");
    REQUIRE(rows.size() == 3);
    CHECK(rows[1][0] == "tripod");
    CHECK(rows[1][col("in_psnr_inside")].empty());
    CHECK(rows[1][col("out_psnr_outside")].empty());
    CHECK(std::isfinite(std::stod(rows[1][col("out_psnr")])));

    // Bad corpora: each refused before any fit, naming the file.
    const fs::path empty = root / "empty";
    fs::create_directories(empty);
    r = cli("bench corpus '" + empty.string() + "' --iters 2");
    CHECK(r.code != 0);
    CHECK(r.output.find(empty.string() + ": no clip folders") != std::string::npos);

    const fs::path devonly = root / "devonly";
    fs::create_directories(devonly);
    fs::copy(corpus / "rack", devonly / "rack");
    r = cli("bench corpus '" + devonly.string() + "' --split val --iters 2");
    CHECK(r.code != 0);
    CHECK(r.output.find(devonly.string() + ": no clips in split 'val'") != std::string::npos);

    fs::remove(devonly / "rack" / "sharp_0005.png");
    r = cli("bench corpus '" + devonly.string() + "' --iters 2");
    CHECK(r.code != 0);
    CHECK(r.output.find((devonly / "rack" / "sharp_%04d.png").string() +
                        ": 5 frames, but 6 input frames") != std::string::npos);

    for (int t = 0; t < 5; ++t) {
        char name[32];
        std::snprintf(name, sizeof name, "sharp_%04d.png", t);
        fs::remove(devonly / "rack" / name);
    }
    r = cli("bench corpus '" + devonly.string() + "' --iters 2");
    CHECK(r.code != 0);
    CHECK(r.output.find((devonly / "rack" / "sharp_%04d.png").string() +
                        ": no ground-truth frames") != std::string::npos);
}

TEST_CASE("bench corpus --views: each pixel from the frame that saw it sharpest") {
    // A hand-made rendered clip: a plane 2 m away, four frames whose camera trucks 2 px to the
    // right at frame 1. Frame 1 is in focus and noiseless; the others are blurred (radius 3, 3,
    // 2 px) and noisy. Every pixel frame 1 sees comes back from it, drawn through the cameras.
    const fs::path root = scratch_dir("bench_corpus_views"), clip = root / "corpus" / "plane";
    fs::create_directories(clip);
    const int T = 4, W = 32, H = 24;
    const double f = 30.0, z = 2.0, shift_px = 2.0;
    const float radius[T] = {3, 0, 3, 2};
    const float* lin = srgb8_to_linear_table();
    auto code = [](int x, int y) { return 40 + (x * 37 + y * 91 + (x * y) % 13) % 170; };
    std::vector<Image> sharp, input;
    nlohmann::json cams = nlohmann::json::array();
    for (int t = 0; t < T; ++t) {
        const int dx = t == 1 ? static_cast<int>(shift_px) : 0;  // frame 1 sees x + 2 at x
        Image s(W, H, 3), in(W, H, 3), depth(W, H, 1, float(z)), coc(W, H, 1, radius[t]);
        for (int y = 0; y < H; ++y)
            for (int x = 0; x < W; ++x)
                for (int c = 0; c < 3; ++c) {
                    const int v = code(x + dx, y) + 10 * c;
                    const int noise = t == 1 ? 0 : ((x * 7 + y * 3 + t * 5 + c) % 17) - 8;
                    s.at(x, y, c) = lin[v];
                    in.at(x, y, c) = lin[std::clamp(v + noise, 0, 255)];
                }
        sharp.push_back(s), input.push_back(in);
        char name[32];
        std::snprintf(name, sizeof name, "depth_%04d.exr", t);
        write_image_file((clip / name).string(), depth, PixelFormat::ExrFloat, false);
        std::snprintf(name, sizeof name, "coc_%04d.exr", t);
        write_image_file((clip / name).string(), coc, PixelFormat::ExrFloat, false);
        // Camera to world, row-major: the camera moves +x by shift·z/f, so the plane moves left.
        const double tx = dx * z / f;
        cams.push_back({1, 0, 0, tx, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1});
    }
    for (int t = 0; t < T; ++t) {
        char name[32];
        std::snprintf(name, sizeof name, "sharp_%04d.png", t);
        write_image_file((clip / name).string(), sharp[t], PixelFormat::Png8);
        std::snprintf(name, sizeof name, "input_%04d.png", t);
        write_image_file((clip / name).string(), input[t], PixelFormat::Png8);
    }
    nlohmann::json j = {{"name", "plane"},     {"split", "val"}, {"width", W},
                        {"height", H},         {"frames", T},    {"lens", {{"focal_px", f}}},
                        {"camera_world", cams}};
    write_file_atomic(clip / "clip.json", j.dump(1));
    const fs::path csv = root / "views.csv";
    RunResult r = cli("bench corpus '" + (root / "corpus").string() + "' --views --csv '" +
                      csv.string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    CHECK(r.output.find("sharpest-view bound") != std::string::npos);
    auto rows = read_csv(csv);
    REQUIRE(rows.size() == 2);
    const std::vector<std::string> h = rows[0];
    auto val = [&](const std::string& name) {
        const auto it = std::find(h.begin(), h.end(), name);
        REQUIRE(it != h.end());
        return std::stod(rows[1][static_cast<size_t>(it - h.begin())]);
    };
    CHECK(rows[1][0] == "plane");
    // The noisy frames' pixels come from frame 1, which sees all but their two left columns
    // (x < 2 lands outside it): those keep a noisy input. The mean holds frame 1 at the 100 dB
    // cap (exact) and three noisy frames near 34 dB.
    CHECK(val("in_psnr") < 55.0);
    CHECK(val("least_psnr") > val("in_psnr") + 5.0);
    CHECK(val("least_worst") >= 0.0);
    CHECK(val("near_psnr") == doctest::Approx(val("least_psnr")).epsilon(1e-6));
    CHECK(val("sharper_share") == doctest::Approx(0.75 * (W - 2) / W).epsilon(1e-6));
    CHECK(val("least_tpsnr") > val("in_tpsnr"));

    // A clip without the cameras (a synth clip's clip.json) is refused, naming the file.
    j.erase("camera_world");
    write_file_atomic(clip / "clip.json", j.dump(1));
    r = cli("bench corpus '" + (root / "corpus").string() + "' --views");
    CHECK(r.code != 0);
    CHECK(r.output.find((clip / "clip.json").string() + ": no camera_world") != std::string::npos);
}
