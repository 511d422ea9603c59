#include "test_util.h"

#include <sys/wait.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <random>

#include <torch/torch.h>
#undef CHECK  // glog's (through torch), which aborts: doctest's below

#include <doctest/doctest.h>

#include <nlohmann/json.hpp>

#include "model/fit_model.h"
#include "io/clip.h"
#include "io/image_file.h"

namespace refocus::test {

fs::path scratch_dir(const std::string& name) {
    fs::path d = fs::path(REFOCUS_TEST_TMP) / name;
    fs::remove_all(d);
    fs::create_directories(d);
    return d;
}

RunResult run(const std::string& command) {
    RunResult r;
    FILE* p = ::popen((command + " 2>&1").c_str(), "r");
    if (!p) return r;
    std::array<char, 4096> buf;
    size_t n;
    while ((n = std::fread(buf.data(), 1, buf.size(), p)) > 0) r.output.append(buf.data(), n);
    int status = ::pclose(p);
    r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    return r;
}

RunResult cli(const std::string& args) {
    return run(std::string(REFOCUS_CLI) + " " + args);
}

Image pattern_frame(int w, int h, int t, unsigned seed) {
    Image img(w, h, 3);
    std::mt19937 rng(seed);
    std::uniform_real_distribution<float> noise(-0.03f, 0.03f);
    const float cx = 0.3f * w + 3.0f * t, cy = 0.5f * h, rad = 0.15f * std::min(w, h);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            float gx = float(x) / w, gy = float(y) / h;
            bool check = ((x / 4) + (y / 4)) % 2 == 0;
            float base[3] = {0.1f + 0.6f * gx, 0.1f + 0.6f * gy, check ? 0.6f : 0.15f};
            float dx = x - cx, dy = y - cy;
            if (dx * dx + dy * dy < rad * rad) {
                base[0] = 0.9f;
                base[1] = 0.3f;
                base[2] = 0.1f;
            }
            for (int c = 0; c < 3; ++c)
                img.at(x, y, c) = std::clamp(base[c] + noise(rng), 0.0f, 1.0f);
        }
    return img;
}

void write_png_sequence(const fs::path& dir, const std::vector<Image>& frames, bool sixteen) {
    fs::create_directories(dir);
    for (size_t i = 0; i < frames.size(); ++i) {
        char name[64];
        std::snprintf(name, sizeof name, "frame_%04zu.png", i);
        write_image_file((dir / name).string(), frames[i],
                         sixteen ? PixelFormat::Png16 : PixelFormat::Png8);
    }
}

double max_abs_diff(const Image& a, const Image& b) {
    double m = 0;
    for (size_t i = 0; i < a.size(); ++i)
        m = std::max(m, std::abs(double(a.pixels[i]) - b.pixels[i]));
    return m;
}

TinyClip make_tiny(const std::string& name, const std::string& scene, const std::string& size) {
    TinyClip c;
    c.dir = scratch_dir(name);
    c.clip = c.dir / "clip";
    RunResult r = cli("synth --scene " + scene + " -o '" + c.clip.string() + "' --size " + size +
                      " --frames 8 --seed 3");
    INFO(r.output);
    REQUIRE(r.code == 0);
    c.project = c.dir / "proj";
    r = cli("new '" + (c.clip / "input_%04d.png").string() + "' -o '" + c.project.string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    return c;
}

std::vector<Image> export_sharp(const TinyClip& c, const std::string& sub, std::string* output) {
    fs::path out = c.dir / sub;
    RunResult r = cli("export '" + c.project.string() + "' --what sharp --format exr32 --out '" +
                      out.string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    if (output) *output = r.output;
    return read_all_frames((out / "sharp_%04d.exr").string());
}

void strip_checksums(nlohmann::json& j) {
    for (const char* key : {"checksum", "tensors_checksum", "checksums"}) j.erase(key);
}

void set_project_setting(const fs::path& project, const std::string& name,
                         std::optional<double> value) {
    const fs::path path = project / "project.json";
    nlohmann::json j = nlohmann::json::parse(read_text_file(path));
    auto& settings = j["fit"]["settings"];
    if (value)
        settings[name] = *value;
    else if (settings.is_object())
        settings.erase(name);
    write_file_atomic(path, j.dump(1));
}

std::shared_ptr<FitData> tiny_two_layer_data(unsigned seed, bool with_flow) {
    auto data = std::make_shared<FitData>();
    data->frames = 4, data->height = 24, data->width = 40;
    torch::manual_seed(seed);
    data->input = torch::rand({4, 3, 24, 40});
    data->radius = torch::full({4, 24, 40}, 1.0f);
    data->to_ref = torch::eye(3, torch::kFloat64).expand({4, 3, 3}).clone();
    data->mask = torch::zeros({4, 1, 24, 40});
    data->mask.narrow(2, 8, 8).narrow(3, 12, 10).fill_(1.0f);
    data->has_subject = true;
    if (with_flow) {
        data->flow_fwd = torch::zeros({3, 2, 24, 40});
        data->flow_valid = torch::ones({3, 1, 24, 40});
    }
    return data;
}

}  // namespace refocus::test
