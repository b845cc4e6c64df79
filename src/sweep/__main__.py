"""``python -m sweep [overrides] [-m]``: one Hydra job per agent/wind/seed (see conf/config.yaml)."""
import hydra
from omegaconf import DictConfig

from sweep.run import run_job


@hydra.main(version_base="1.3", config_path="../../conf", config_name="config")
def main(cfg: DictConfig) -> None:
    run_job(cfg)


if __name__ == "__main__":
    main()
