#include "model/clip_cache.h"

#include <signal.h>
#include <unistd.h>

#include <atomic>
#include <cstring>

#include <torch/torch.h>

#include "util/error.h"
#include "util/fs.h"
#include "util/mapped.h"

namespace refocus {

using nlohmann::json;

namespace {

fs::path array_file(const FitData& d, const std::string& name) {
    return d.cache_dir / (name + ".f32");
}

fs::path sidecar(const FitData& d, const std::string& name) {
    return d.cache_dir / (name + ".json");
}

json shape_json(at::IntArrayRef shape) {
    json s = json::array();
    for (int64_t v : shape) s.push_back(v);
    return s;
}

// Files a crashed command left unpublished (".tmp-<pid>-<n>" of a process no longer running).
void remove_stale(const fs::path& dir) {
    std::error_code ec;
    for (const auto& e : fs::directory_iterator(dir, ec)) {
        const std::string n = e.path().filename().string();
        const auto at = n.find(".tmp-");
        if (at == std::string::npos) continue;
        const long pid = std::atol(n.c_str() + at + 5);
        if (pid > 0 && pid != long(::getpid()) && ::kill(pid_t(pid), 0) != 0 && errno == ESRCH)
            fs::remove(e.path(), ec);
    }
}

}  // namespace

torch::Tensor new_kept_array(const FitData& d, const std::string& name, at::IntArrayRef shape) {
    static std::atomic<int> counter{0};
    std::error_code ec;
    fs::create_directories(d.cache_dir, ec);
    remove_stale(d.cache_dir);
    const fs::path file = d.cache_dir / (name + ".f32.tmp-" + std::to_string(::getpid()) + "-" +
                                         std::to_string(counter++));
    torch::Tensor t = mapped_file_tensor(file, shape, true);
    // A name made again in this command (a model rebuilt) replaces its unpublished file.
    const auto old = d.cache_pending.find(name);
    if (old != d.cache_pending.end()) fs::remove(old->second.first, ec);
    d.cache_pending[name] = {file, t};
    return t;
}

void keep_clip_array(const FitData& d, const std::string& name, const torch::Tensor& t,
                     const std::string& key) {
    if (d.cache_dir.empty() || !t.defined()) return;
    std::error_code ec;
    fs::path made;
    const auto p = d.cache_pending.find(name);
    if (p != d.cache_pending.end() && p->second.second.data_ptr() == t.data_ptr() &&
        p->second.second.numel() == t.numel() && t.is_contiguous() &&
        t.scalar_type() == torch::kFloat32) {
        made = p->second.first;
        d.cache_pending.erase(p);
    } else {
        fs::create_directories(d.cache_dir, ec);
        made = d.cache_dir / (name + ".f32.tmp-" + std::to_string(::getpid()) + "-copy");
        torch::Tensor copy = mapped_file_tensor(made, t.sizes(), true);
        // Frame by frame: a clip-sized temporary is what the mappings avoid.
        for (int64_t i = 0; i < t.size(0); ++i) copy[i].copy_(t[i]);
    }
    // The data first, then the sidecar that vouches for it: a reader that finds the new sidecar
    // finds the new data; one that finds the old sidecar refuses the new data by its key.
    fs::rename(made, array_file(d, name), ec);
    if (ec)
        throw Error(file_error(array_file(d, name).string(), "cannot keep it: " + ec.message()));
    write_file_atomic(sidecar(d, name),
                      json{{"key", key}, {"shape", shape_json(t.sizes())}}.dump());
}

torch::Tensor kept_clip_array(const FitData& d, const std::string& name, at::IntArrayRef shape,
                              const std::string& key) {
    if (d.cache_dir.empty()) return {};
    try {
        const json j = json::parse(read_text_file(sidecar(d, name)));
        if (j.value("key", std::string()) != key || j.value("shape", json()) != shape_json(shape))
            return {};
        return mapped_file_tensor(array_file(d, name), shape, false);
    } catch (const std::exception&) {
        return {};  // absent or damaged: made again
    }
}

void keep_clip_manifest(const FitData& d, const json& j) {
    if (d.cache_dir.empty()) return;
    json m = j;
    m["key"] = d.cache_key;
    write_file_atomic(d.cache_dir / "clip.json", m.dump());
}

json kept_clip_manifest(const FitData& d) {
    if (d.cache_dir.empty()) return nullptr;
    remove_stale(d.cache_dir);
    try {
        json j = json::parse(read_text_file(d.cache_dir / "clip.json"));
        if (j.value("key", std::string()) != d.cache_key) return nullptr;
        return j;
    } catch (const std::exception&) {
        return nullptr;
    }
}

}  // namespace refocus
